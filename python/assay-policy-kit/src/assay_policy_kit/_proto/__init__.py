"""Generated stubs of proto/assay/v1/policy.proto and world_model.proto (see generate_stubs.sh; do
not edit them)."""
