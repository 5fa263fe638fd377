#!/usr/bin/env python3
"""Write bench/embeddings/corpus.txt: ~1000 deterministic task-description-like
sentences (templates x verbs x objects x colours), about 5-60 words each.
One sentence per line, UTF-8. GenSim-style "Task: ... \\n Description: ..."
lines keep the two characters backslash-n literally (no line breaks inside a
sentence), so every engine that reads the file must take each line verbatim.

    python bench/embeddings/make_corpus.py [--n 1000] [--out bench/embeddings/corpus.txt]
"""
import argparse
import os
import random

VERBS = ["pick up", "place", "stack", "push", "slide", "rotate", "insert", "align",
         "sort", "move", "lift", "drop", "open", "close", "put", "arrange"]
OBJECTS = ["block", "cube", "bowl", "cylinder", "drawer", "rope", "peg", "ball",
           "cup", "plate", "sponge", "box", "lid", "handle", "tray", "cone"]
COLOURS = ["red", "green", "blue", "yellow", "purple", "orange", "pink", "white",
           "black", "brown", "gray", "cyan"]
PLACES = ["on the table", "into the bowl", "inside the box", "next to the wall",
          "on top of the tower", "in the left corner", "near the robot base",
          "onto the shelf", "into the matching zone", "behind the cabinet"]
ADVERBS = ["carefully", "quickly", "slowly", "gently", "precisely"]
CLAUSES = [
    "without knocking over any other objects",
    "so that the {c} {o} ends up centred",
    "while keeping the gripper above the table",
    "and then return the arm to its home pose",
    "making sure the {c} {o} does not touch the {c2} {o2}",
    "in order of increasing size from left to right",
    "after checking that the {o} is empty",
    "using at most {k} grasps",
]


def task_name(rng):
    return "-".join(rng.sample(["stack", "blocks", "tower", "place", "color", "zone",
                                "align", "rope", "sort", "insert", "build", "pyramid",
                                "bowl", "drawer", "open", "line"], rng.randint(2, 4)))


def clause(rng):
    return rng.choice(CLAUSES).format(c=rng.choice(COLOURS), o=rng.choice(OBJECTS),
                                      c2=rng.choice(COLOURS), o2=rng.choice(OBJECTS),
                                      k=rng.randint(2, 9))


def sentence(rng, target):
    v, o, c, p = rng.choice(VERBS), rng.choice(OBJECTS), rng.choice(COLOURS), rng.choice(PLACES)
    style = rng.randrange(3)
    if style == 0:
        s = "Task: %s \n Description: %s the %s %s %s" % (task_name(rng), v, c, o, p)
    elif style == 1:
        s = "%s the %s %s" % (v, o, p)
    else:
        s = "%s %s the %d %s %ss %s" % (rng.choice(ADVERBS).capitalize(), v, rng.randint(2, 6),
                                         c, o, p)
    while len(s.split()) < target:
        s += ", " + clause(rng) if rng.random() < 0.7 else \
            ". Then %s the %s %s %s" % (rng.choice(VERBS), rng.choice(COLOURS),
                                        rng.choice(OBJECTS), rng.choice(PLACES))
    words = s.split(" ")
    if len(s.split()) > 60:
        s = " ".join(words[:60])
    return s.rstrip(",") + "."


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=20240601)
    ap.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)),
                                                  "corpus.txt"))
    args = ap.parse_args()
    rng = random.Random(args.seed)
    lines = []
    for _ in range(args.n):
        # mostly short instructions, a tail of long descriptions
        target = rng.choice([5, 6, 8, 10, 12, 15, 20, 25, 30, 40, 50, 60])
        lines.append(sentence(rng, target).replace("\n", "\\n"))
    with open(args.out, "w", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
