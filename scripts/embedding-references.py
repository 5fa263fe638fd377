#!/usr/bin/env python3
"""Write reference sentence embeddings computed by the real sentence-transformers
library, for the Rust embedding tests to compare against.

    python scripts/embedding-references.py \
        --model-dir DIR --name all-MiniLM-L6-v2 \
        --out workers/embed/tests/data/all-MiniLM-L6-v2-reference.json

The model directory is a sentence-transformers checkout (modules.json,
sentence_bert_config.json, 1_Pooling/, config.json, model.safetensors,
tokenizer.json). It is loaded with SentenceTransformer(path, device="cpu"),
so the whole pipeline (Transformer -> mean Pooling -> Normalize, and the
library's own max_seq_length truncation) is what produced the vectors.

Output JSON:
  model, library, torch, transformers, tokenizers, max_seq_length, normalize,
  pooling, dim, batch_size, sentences, tokens (token count per sentence with
  special tokens, after truncation), input_ids (per sentence, after
  truncation, no padding), vectors (float32 printed with 9 significant digits,
  which round-trips float32 exactly), and batch_vs_single_max_abs_diff (how much
  the vectors move between batch_size=N and batch_size=1, i.e. the padding
  noise that any tolerance must allow for).
"""
import argparse
import json
import os
import sys

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
os.environ.setdefault("TOKENIZERS_PARALLELISM", "false")


def _long_text(n_parts):
    parts = [
        "Task: build-two-circles.",
        "Description: construct two distinct circles on the table using ten red and ten blue blocks,",
        "each circle must contain exactly one colour and the circles must not touch each other.",
        "Then pick up the green cylinder near the left edge of the workspace and place it in the",
        "middle of the red circle without knocking over any of the blocks that were already placed.",
        "Finally, open the top drawer of the cabinet by pulling its handle, put the small yellow",
        "sponge inside, and close the drawer again; the robot arm should return to its home pose",
        "at (0.35, -0.12, 0.40) metres after 3 attempts at most.",
    ]
    out = []
    i = 0
    while len(out) < n_parts:
        out.append(parts[i % len(parts)])
        i += 1
    return " ".join(out)


SENTENCES = [
    # GenSim-style task descriptions
    "Task: stack-blocks-tower \n Description: stack three blocks of different colors into a tower",
    "Task: align-rope \n Description: manipulate a deformable rope to connect its end-points between two corners of a 3-sided square.",
    "Task: place-red-in-green \n Description: pick up the red blocks and place them into the green bowls amidst other objects.",
    "Task: color-coordinated-zone-stacking \n Description: On the tabletop, there are three zones marked in different colors (red, blue, green). Stack blocks of matching color in each zone.",
    "stack-blocks-tower",
    "build a car with blocks",
    # RoboGen / BBSEA style
    "open the drawer using handle",
    "close the microwave door",
    "Turn the faucet handle to open the water flow.",
    "move the laptop lid to a half-open position",
    "pick up the bowl and put it on the shelf",
    "push the red cube to the left of the blue cube",
    # punctuation, digits
    "pick-and-place: (red) block -> [blue] bowl!!! ...?",
    "rotate 90 degrees, then move 0.25 m to x=1.5, y=-3; repeat 10x",
    "the 2nd, 3rd and 4th cubes are 5cm x 5cm x 5cm (125 cm^3 each).",
    "\"quoted\" 'single' `backtick` #hash @at $dollar %percent ^caret &amp *star",
    # case
    "PICK UP THE RED BLOCK AND PUT IT IN THE BROWN BOX",
    "Pick Up The Red Block And Put It In The Brown Box",
    # unicode
    "Déplacez le cube rouge près de la tasse à café",
    "Schließe die Schublade und öffne den Kühlschrank",
    "把红色方块放到蓝色碗里",
    "赤いブロックを青いボウルに入れてください",
    "빨간 블록을 파란 그릇에 넣으세요",
    "put the 🍎 in the bowl 🥣 then wave 👋",
    "naïve café résumé coöperate ñandú",
    "Ελληνικά και русский текст mixed with English",
    "combining accents: e\u0301 a\u0300 o\u0308",
    # whitespace and degenerate inputs
    "",
    "   ",
    "stack   the    blocks\t\tinto  a\n\ntower",
    "a",
    "the the the the the the the the the the",
    "supercalifragilisticexpialidocious" * 4,
    "block",
    # lengths: ~150 word pieces (between 128 and 256), >256, >384 (so that
    # all-mpnet-base-v2's 384 limit also truncates)
    _long_text(12),
    _long_text(24),
    _long_text(40),
    # more ordinary ones
    "insert the peg into the hole on the board",
    "sort the blocks by colour into matching zones",
    "sweep the small cubes into the dustpan with the brush",
]


def fmt(x):
    return "%.9g" % x


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--model-dir", required=True)
    ap.add_argument("--name", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--batch-size", type=int, default=8)
    args = ap.parse_args()

    import numpy as np
    import sentence_transformers
    import tokenizers
    import torch
    import transformers
    from sentence_transformers import SentenceTransformer

    torch.manual_seed(0)
    model = SentenceTransformer(args.model_dir, device="cpu")
    model.eval()
    max_len = int(model.max_seq_length)
    modules = [type(m).__name__ for m in model]
    normalize = "Normalize" in modules

    vecs = model.encode(SENTENCES, normalize_embeddings=True, batch_size=args.batch_size,
                        convert_to_numpy=True, show_progress_bar=False)
    vecs = np.asarray(vecs, dtype=np.float32)
    single = np.asarray(model.encode(SENTENCES, normalize_embeddings=True, batch_size=1,
                                     convert_to_numpy=True, show_progress_bar=False),
                        dtype=np.float32)
    diff = float(np.max(np.abs(vecs - single)))

    # What the library actually feeds the transformer (its own truncation).
    tokens, input_ids = [], []
    for s in SENTENCES:
        feats = model.preprocess([s]) if hasattr(model, "preprocess") else model.tokenize([s])
        mask = feats["attention_mask"][0]
        ids = feats["input_ids"][0][mask.bool()].tolist()
        tokens.append(len(ids))
        input_ids.append(ids)
    # Cross-check with the plain HF tokenizer at the same max_length.
    hf = model.tokenizer(SENTENCES, truncation=True, max_length=max_len)["input_ids"]
    assert [list(x) for x in hf] == input_ids, "library preprocess != tokenizer(max_length)"

    pooling = None
    for m in model:
        if type(m).__name__ == "Pooling":
            pooling = getattr(m, "pooling_mode", None) or m.get_pooling_mode_str()

    lines = []
    lines.append("{")
    meta = {
        "model": args.name,
        "library": "sentence-transformers " + sentence_transformers.__version__,
        "torch": torch.__version__,
        "transformers": transformers.__version__,
        "tokenizers": tokenizers.__version__,
        "max_seq_length": max_len,
        "normalize": normalize,
        "pooling": pooling,
        "modules": modules,
        "dim": int(vecs.shape[1]),
        "batch_size": args.batch_size,
        "batch_vs_single_max_abs_diff": float("%.3g" % diff),
    }
    for k, v in meta.items():
        lines.append("  %s: %s," % (json.dumps(k), json.dumps(v)))
    lines.append('  "sentences": [')
    lines.append(",\n".join("    " + json.dumps(s, ensure_ascii=False) for s in SENTENCES))
    lines.append("  ],")
    lines.append('  "tokens": %s,' % json.dumps(tokens))
    lines.append('  "input_ids": [')
    lines.append(",\n".join("    " + json.dumps(ids, separators=(",", ":")) for ids in input_ids))
    lines.append("  ],")
    lines.append('  "vectors": [')
    lines.append(",\n".join("    [" + ",".join(fmt(x) for x in row) + "]" for row in vecs))
    lines.append("  ]")
    lines.append("}")
    text = "\n".join(lines) + "\n"
    parsed = json.loads(text)  # sanity: valid JSON, float32 round-trip
    back = np.asarray(parsed["vectors"], dtype=np.float32)
    assert np.array_equal(back, vecs)

    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w", encoding="utf-8") as f:
        f.write(text)
    print("wrote %s: %d sentences x %d dims, max_seq_length=%d, tokens=%s, "
          "batch-vs-single max |diff|=%.3g"
          % (args.out, len(SENTENCES), vecs.shape[1], max_len, tokens, diff), file=sys.stderr)


if __name__ == "__main__":
    main()
