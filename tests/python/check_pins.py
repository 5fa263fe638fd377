"""Checks that a pinned set installed with `pip install --no-deps -r FILE` is complete: pip
resolves the set with its dependencies (a dry run, metadata only) and every package it would
install must be pinned in FILE at that version, or match one of the ALLOWED patterns (packages the
script deliberately leaves out). Prints JSON {"unpinned": [...], "mismatched": [...]} and exits 1
when either is non-empty. Used by tests/it/scripts.rs.

    python check_pins.py REQUIREMENTS [ALLOWED_REGEX ...]
"""

import json
import re
import subprocess
import sys
import tempfile


def norm(name):
    return re.sub(r"[-_.]+", "-", name).lower()


def main():
    req, allowed = sys.argv[1], [re.compile(p) for p in sys.argv[2:]]
    pins = {}
    for line in open(req):
        line = line.split("#", 1)[0].strip()
        if line:
            name, _, version = line.partition("==")
            pins[norm(name)] = version.strip()
    with tempfile.NamedTemporaryFile(suffix=".json") as report:
        subprocess.run(
            [sys.executable, "-m", "pip", "install", "--dry-run", "--ignore-installed", "--quiet",
             "--disable-pip-version-check", "--report", report.name, "-r", req],
            check=True,
        )
        resolved = json.load(open(report.name))["install"]
    unpinned, mismatched = [], []
    for item in resolved:
        name, version = norm(item["metadata"]["name"]), item["metadata"]["version"]
        if name in pins:
            if pins[name] and pins[name] != version:
                mismatched.append(f"{name}: pinned {pins[name]}, resolved {version}")
        elif not any(p.fullmatch(name) for p in allowed):
            unpinned.append(f"{name}=={version}")
    print(json.dumps({"unpinned": sorted(unpinned), "mismatched": sorted(mismatched)}))
    sys.exit(1 if unpinned or mismatched else 0)


main()
