"""Reads the scalars of a TensorBoard log folder with tbparse (TensorBoard's own event reader
underneath) and prints them as one JSON list of {tag, step, value}.

    python read_tensorboard.py LOGDIR
"""

import json
import sys

from tbparse import SummaryReader

scalars = SummaryReader(sys.argv[1]).scalars
print(json.dumps([
    {"tag": tag, "step": int(step), "value": float(value)}
    for tag, step, value in zip(scalars["tag"], scalars["step"], scalars["value"])
]))
