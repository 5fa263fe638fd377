"""Reads a report's episodes.parquet with pyarrow and prints its schema and rows as JSON (used by
tests/it/eval.rs): the table as a lab's pandas or polars script would get it."""

import json
import sys

import pyarrow.parquet

table = pyarrow.parquet.read_table(sys.argv[1])
print(json.dumps({
    "columns": table.column_names,
    "types": [str(t) for t in table.schema.types],
    "rows": table.to_pylist(),
}))
