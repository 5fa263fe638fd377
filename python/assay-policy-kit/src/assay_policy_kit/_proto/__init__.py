"""Generated stubs of proto/assay/v1/policy.proto (see generate_stubs.sh; do not edit them)."""
