#!/usr/bin/env bash
# Regenerates the Python gRPC stubs of the Assay policy kit from proto/assay/v1/policy.proto and
# proto/assay/v1/world_model.proto.
#
#   python/assay-policy-kit/generate_stubs.sh [OUT_DIR]
#
# OUT_DIR defaults to src/assay_policy_kit/_proto (the checked-in stubs); a test regenerates into a
# temporary directory and diffs. Needs grpcio-tools (pinned in tests/python/requirements.txt: the
# checked-in files are byte-identical to what that version produces). $PYTHON picks the
# interpreter (default: python3).
set -euo pipefail

kit_dir="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
repo_root="$(cd "$kit_dir/../.." && pwd)"
out_dir="${1:-$kit_dir/src/assay_policy_kit/_proto}"
python="${PYTHON:-python3}"
names=(policy world_model)

mkdir -p "$out_dir"
out_dir="$(cd "$out_dir" && pwd)"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT

# -I proto keeps the descriptors' file names "assay/v1/<name>.proto" (as in every other language's
# stubs); protoc then writes assay/v1/<name>_pb2*.py under $tmp.
(cd "$repo_root" && "$python" -m grpc_tools.protoc -I proto \
    --python_out="$tmp" --grpc_python_out="$tmp" \
    assay/v1/policy.proto assay/v1/world_model.proto)

# The generated modules import each other as the top-level package `assay.v1`; inside the kit they
# are sibling modules.
for name in "${names[@]}"; do
    for suffix in pb2 pb2_grpc; do
        sed -e 's/^from assay\.v1 import \([a-z_]*_pb2\) as /from . import \1 as /' \
            "$tmp/assay/v1/${name}_${suffix}.py" > "$out_dir/${name}_${suffix}.py"
        if grep -q '^from assay\.v1 import\|^import assay\.' "$out_dir/${name}_${suffix}.py"; then
            echo "generate_stubs.sh: could not fix the imports in ${name}_${suffix}.py" >&2
            exit 1
        fi
    done
    grep -q "^from \. import ${name}_pb2 as " "$out_dir/${name}_pb2_grpc.py" || {
        echo "generate_stubs.sh: could not fix the import in ${name}_pb2_grpc.py" >&2
        exit 1
    }
done
