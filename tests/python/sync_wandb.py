"""Uploads a W&B offline run with the real `wandb sync` (wandb-core reads the .wandb file) to a
stand-in for W&B's server on loopback, and prints what arrived as one JSON object:

    {"exit_code": 0, "output": "...", "operations": [...], "run": {...upsertBucket variables...},
     "config": {...}, "history": [{...row...}, ...], "summary": {...}, "complete": true}

    python sync_wandb.py RUN_DIR

The stand-in speaks the part of W&B's protocol a sync uses: GraphQL at /graphql (ServerFeaturesQuery,
UpsertBucket; every other operation gets an empty `data`) and the file stream at
/files/<entity>/<project>/<run>/file_stream, whose `wandb-history.jsonl` lines and
`wandb-summary.json` it keeps. It is a fixture for a hosted service that cannot run here, nothing
more: it checks no key and stores nothing else.
"""

import json
import os
import subprocess
import sys
import tempfile
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

received = {"operations": [], "run": None, "history": {}, "summary": {}, "complete": False}
lock = threading.Lock()


class Server(BaseHTTPRequestHandler):
    def do_POST(self):
        length = int(self.headers.get("content-length") or 0)
        raw = self.rfile.read(length)
        with lock:
            if self.path == "/graphql":
                answer = self.graphql(json.loads(raw))
            elif self.path.endswith("/file_stream"):
                answer = self.stream(json.loads(raw))
            else:
                # Anything else (wandb-core's own telemetry) is taken and ignored.
                received["operations"].append(f"POST {self.path}")
                answer = {}
        data = json.dumps(answer).encode()
        self.send_response(200)
        self.send_header("content-type", "application/json")
        self.send_header("content-length", str(len(data)))
        self.end_headers()
        self.wfile.write(data)

    def graphql(self, body):
        op = body.get("operationName")
        received["operations"].append(op)
        if op == "ServerFeaturesQuery":
            return {"data": {"serverInfo": {"features": []}}}
        if op == "UpsertBucket":
            v = body.get("variables") or {}
            # The first upsert creates the run; later ones (at the end) update a few fields.
            received["run"] = received["run"] or v
            return {"data": {"upsertBucket": {"inserted": True, "bucket": {
                "id": "bucket-1", "name": v.get("name"), "displayName": v.get("displayName"),
                "description": None, "config": v.get("config"), "sweepName": None,
                "historyLineCount": 0,
                "project": {"id": "project-1", "name": v.get("project"),
                            "entity": {"id": "entity-1", "name": v.get("entity")}}}}}}
        return {"data": {}}

    def stream(self, body):
        received["operations"].append("file_stream")
        files = body.get("files") or {}
        history = files.get("wandb-history.jsonl") or {}
        # Lines are numbered by the chunk's offset: a chunk sent again replaces, never repeats.
        for i, line in enumerate(history.get("content", [])):
            received["history"][history.get("offset", 0) + i] = json.loads(line)
        for line in (files.get("wandb-summary.json") or {}).get("content", []):
            received["summary"] = json.loads(line)
        if body.get("complete"):
            received["complete"] = True
            received["exitcode"] = body.get("exitcode")
        return {}

    def log_message(self, *args):
        pass


def main():
    run_dir = Path(sys.argv[1])
    server = ThreadingHTTPServer(("127.0.0.1", 0), Server)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    wandb = Path(sys.executable).with_name("wandb")
    run_dir = run_dir.resolve()
    with tempfile.TemporaryDirectory() as home:
        env = dict(os.environ)
        env.update({
            "WANDB_BASE_URL": f"http://127.0.0.1:{server.server_port}",
            "WANDB_API_KEY": "local-" + "0" * 40,
            "WANDB_CONFIG_DIR": home, "WANDB_CACHE_DIR": home, "WANDB_DATA_DIR": home,
            "HOME": home, "WANDB_SILENT": "false",
            # No error reports to W&B's Sentry: nothing leaves loopback.
            "WANDB_ERROR_REPORTING": "false",
        })
        proc = subprocess.run(
            [str(wandb), "sync", "--include-synced", "--entity", "assay-test", str(run_dir)],
            env=env, capture_output=True, text=True, timeout=120,
            # wandb writes its debug logs to ./wandb: keep them out of the caller's folder.
            cwd=home,
        )
    server.shutdown()
    config = json.loads((received["run"] or {}).get("config") or "{}")
    print(json.dumps({
        "exit_code": proc.returncode,
        "output": proc.stdout + proc.stderr,
        "operations": received["operations"],
        "run": received["run"],
        "config": {k: v.get("value") for k, v in config.items() if isinstance(v, dict)},
        "history": [received["history"][i] for i in sorted(received["history"])],
        "summary": received["summary"],
        "complete": received["complete"],
        "exitcode": received.get("exitcode"),
    }))


main()
