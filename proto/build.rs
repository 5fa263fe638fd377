fn main() -> Result<(), Box<dyn std::error::Error>> {
    // protoc comes vendored: no system package needed.
    let protoc = protoc_bin_vendored::protoc_bin_path()?;
    set_protoc(&protoc);
    tonic_prost_build::configure()
        // Frames are shared between subscribers without copying their pixels.
        .bytes(".assay.v1.Frame.data")
        .compile_protos(
            &[
                "assay/v1/common.proto",
                "assay/v1/coordinator.proto",
                "assay/v1/frames.proto",
                "assay/v1/policy.proto",
                "assay/v1/worker.proto",
                "assay/v1/world_model.proto",
            ],
            &["."],
        )?;
    println!("cargo:rerun-if-changed=assay");
    Ok(())
}

#[allow(unsafe_code)]
fn set_protoc(path: &std::path::Path) {
    // SAFETY: build.rs is single-threaded here; nothing else reads the environment concurrently.
    unsafe { std::env::set_var("PROTOC", path) };
}
