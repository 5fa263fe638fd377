#!/usr/bin/env python3
"""Sentence-embedding throughput of the reference Python stack
(sentence-transformers on CPU), for comparison with Assay's Rust engine.

    python bench/embeddings/python_bench.py --model-dir DIR \
        --sentences bench/embeddings/corpus.txt --batch-size 32 --repeat 3 --threads 1

Prints one JSON line:
  {"engine":"sentence-transformers","version":...,"torch":...,"threads":...,
   "sentences":n,"seconds":...,"cpu_seconds":...,"sentences_per_s":...,
   "sentences_per_cpu_s":...}
"sentences" is the number encoded in the timed part (corpus lines x repeat).
One untimed warm-up pass over the whole corpus runs first. The HF tokenizer
runs single-threaded (TOKENIZERS_PARALLELISM=false) so that --threads is the
only parallelism. encode() sorts each call's inputs by length before batching
(that is the library's behaviour, kept as is), normalises the output
(normalize_embeddings=True) and returns numpy float32.
"""
import argparse
import json
import os
import sys
import time

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
os.environ["TOKENIZERS_PARALLELISM"] = "false"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--model-dir", required=True)
    ap.add_argument("--sentences", required=True, help="UTF-8 file, one sentence per line")
    ap.add_argument("--batch-size", type=int, default=32)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--name", default=None, help="model name to report (default: dir name)")
    args = ap.parse_args()

    import torch
    torch.set_num_threads(args.threads)
    import sentence_transformers
    from sentence_transformers import SentenceTransformer

    with open(args.sentences, encoding="utf-8") as f:
        sentences = [line.rstrip("\n") for line in f if line.strip()]

    model = SentenceTransformer(args.model_dir, device="cpu")
    model.eval()

    def run():
        return model.encode(sentences, batch_size=args.batch_size, normalize_embeddings=True,
                            convert_to_numpy=True, show_progress_bar=False)

    with torch.inference_mode():
        out = run()  # warm-up
        dim = int(out.shape[1])
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(args.repeat):
            run()
        seconds = time.perf_counter() - t0
        cpu_seconds = time.process_time() - c0

    n = len(sentences) * args.repeat
    print(json.dumps({
        "engine": "sentence-transformers",
        "version": sentence_transformers.__version__,
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "model": args.name or os.path.basename(os.path.normpath(args.model_dir)),
        "dim": dim,
        "max_seq_length": int(model.max_seq_length),
        "batch_size": args.batch_size,
        "repeat": args.repeat,
        "sentences": n,
        "seconds": round(seconds, 4),
        "cpu_seconds": round(cpu_seconds, 4),
        "sentences_per_s": round(n / seconds, 2),
        "sentences_per_cpu_s": round(n / cpu_seconds, 2) if cpu_seconds > 0 else None,
    }))
    sys.stdout.flush()


if __name__ == "__main__":
    main()
