#!/usr/bin/env bash
# Regenerates the Python gRPC stubs of the Assay policy kit from proto/assay/v1/policy.proto.
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

mkdir -p "$out_dir"
out_dir="$(cd "$out_dir" && pwd)"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT

# -I proto keeps the descriptor's file name "assay/v1/policy.proto" (as in every other language's
# stubs); protoc then writes assay/v1/policy_pb2*.py under $tmp.
(cd "$repo_root" && "$python" -m grpc_tools.protoc -I proto \
    --python_out="$tmp" --grpc_python_out="$tmp" assay/v1/policy.proto)

cp "$tmp/assay/v1/policy_pb2.py" "$out_dir/policy_pb2.py"
# The grpc module imports its messages as the top-level package `assay.v1`; inside the kit they
# are a sibling module.
sed -e 's/^from assay\.v1 import policy_pb2 as /from . import policy_pb2 as /' \
    "$tmp/assay/v1/policy_pb2_grpc.py" > "$out_dir/policy_pb2_grpc.py"
grep -q '^from \. import policy_pb2 as ' "$out_dir/policy_pb2_grpc.py" || {
    echo "generate_stubs.sh: could not fix the import in policy_pb2_grpc.py" >&2
    exit 1
}
