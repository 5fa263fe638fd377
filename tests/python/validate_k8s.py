"""Validates deploy/k8s as `kubectl apply -k` would see it, against Kubernetes' own OpenAPI
schemas (the kubernetes-validate package ships them; no network):

- every kustomization's resources and patches exist;
- every resource of the base validates strictly (unknown fields are errors);
- every overlay's patches, merged into the base resource they patch (strategic merge: maps
  merge, lists of named items merge by name), validate strictly too;
- a resource broken on purpose fails (the check can fail).

Prints one line per checked resource; exits 1 on the first problem.
"""

import copy
import pathlib
import sys

import kubernetes_validate
import yaml

VERSION = "1.31.0"
root = pathlib.Path(sys.argv[1])


def docs(path):
    return [d for d in yaml.safe_load_all(path.read_text()) if d]


def check(doc, where):
    try:
        kubernetes_validate.validate(doc, VERSION, strict=True)
    except kubernetes_validate.ValidationError as e:
        print(f"INVALID {where}: {doc['kind']}/{doc['metadata']['name']}: {e.message} at {list(e.path)}")
        sys.exit(1)
    print(f"ok {where}: {doc['kind']}/{doc['metadata']['name']}")


def merge(base, patch):
    if isinstance(base, dict) and isinstance(patch, dict):
        out = dict(base)
        for k, v in patch.items():
            out[k] = merge(base[k], v) if k in base else v
        return out
    if isinstance(base, list) and isinstance(patch, list) and all(
        isinstance(x, dict) and "name" in x for x in base + patch
    ):
        out = [copy.deepcopy(x) for x in base]
        for p in patch:
            for i, b in enumerate(out):
                if b["name"] == p["name"]:
                    out[i] = merge(b, p)
                    break
            else:
                out.append(p)
        return out
    return patch


def build(folder):
    k = yaml.safe_load((folder / "kustomization.yaml").read_text())
    resources = []
    for r in k.get("resources", []):
        path = folder / r
        if not path.exists():
            print(f"MISSING {folder}/kustomization.yaml names {r}")
            sys.exit(1)
        if path.is_dir():
            resources += build(path)
        else:
            resources += [(d, str(path)) for d in docs(path)]
    for p in k.get("patches", []):
        path = folder / p["path"]
        if not path.exists():
            print(f"MISSING {folder}/kustomization.yaml patch {p['path']}")
            sys.exit(1)
        for patch in docs(path):
            key = (patch["kind"], patch["metadata"]["name"])
            hits = [i for i, (d, _) in enumerate(resources) if (d["kind"], d["metadata"]["name"]) == key]
            if not hits:
                print(f"UNMATCHED patch {path}: {key} is not in the resources")
                sys.exit(1)
            for i in hits:
                resources[i] = (merge(resources[i][0], patch), f"{path} on {resources[i][1]}")
    return resources


folders = sorted(p.parent for p in root.rglob("kustomization.yaml"))
assert folders, f"no kustomization under {root}"
for folder in folders:
    for doc, where in build(folder):
        check(doc, where)

broken = next(d for f in folders for d, _ in build(f) if d["kind"] == "HorizontalPodAutoscaler")
broken = copy.deepcopy(broken)
broken["spec"]["maxReplicas"] = "many"
try:
    kubernetes_validate.validate(broken, VERSION, strict=True)
except kubernetes_validate.ValidationError:
    print("ok: a broken HorizontalPodAutoscaler is refused")
else:
    print("the validator accepted maxReplicas: many")
    sys.exit(1)
