# Sourced by the scripts: one shared cargo target folder outside the clone, so repeated runs on one
# machine build incrementally and clones share dependencies.
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/assay/target}"
export CARGO_TERM_COLOR="${CARGO_TERM_COLOR:-never}"
if ! command -v cargo >/dev/null 2>&1 && [ -x "$HOME/.cargo/bin/cargo" ]; then
  export PATH="$HOME/.cargo/bin:$PATH"
fi
# Mesa and other libraries want a private runtime folder.
if [ -z "${XDG_RUNTIME_DIR:-}" ]; then
  export XDG_RUNTIME_DIR="$HOME/.cache/assay/xdg-runtime"
  mkdir -p "$XDG_RUNTIME_DIR" && chmod 700 "$XDG_RUNTIME_DIR"
fi
# libtorch for the trainer role (tch), installed by scripts/setup-libtorch from PyPI's torch wheel.
if [ -z "${LIBTORCH:-}" ] && [ -f "$HOME/.cache/assay/libtorch-2.13.0/torch/build-version" ]; then
  export LIBTORCH="$HOME/.cache/assay/libtorch-2.13.0/torch"
fi
