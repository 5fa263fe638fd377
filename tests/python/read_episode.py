"""Reads an Assay episode file with pyarrow and prints a JSON summary (used by tests/it/eval.rs)."""

import json
import sys

import pyarrow.ipc

table = pyarrow.ipc.open_file(sys.argv[1]).read_all()
meta = {k.decode(): v.decode() for k, v in (table.schema.metadata or {}).items()}
objects = json.loads(meta["assay.objects"])
last = table.slice(table.num_rows - 1, 1).to_pylist()[0]
print(json.dumps({
    "rows": table.num_rows,
    "task_id": meta["assay.task_id"],
    "seed": int(meta["assay.seed"]),
    "success": meta["assay.success"] == "true",
    "predicates": json.loads(meta["assay.predicates"]),
    "columns": table.column_names[:6],
    "final_positions": {o: [last[f"{o}.x"], last[f"{o}.y"], last[f"{o}.z"]] for o in objects},
}))
