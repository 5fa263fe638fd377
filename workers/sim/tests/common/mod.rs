//! Helpers shared by the sim's integration tests.

/// Column `name` of an episode's Arrow file, as float32 values.
pub fn column(ep: &assay_sim::Episode, name: &str) -> Vec<f32> {
    let reader =
        arrow_ipc::reader::FileReader::try_new(std::io::Cursor::new(ep.file.clone()), None)
            .unwrap();
    let batch = reader.into_iter().next().unwrap().unwrap();
    batch
        .column_by_name(name)
        .unwrap_or_else(|| panic!("no column {name}"))
        .as_any()
        .downcast_ref::<arrow_array::Float32Array>()
        .unwrap()
        .values()
        .to_vec()
}
