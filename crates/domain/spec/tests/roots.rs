//! The roots of a process that sets none: its working folder, and nothing a task names. One test
//! (the roots are the process's, set once): a worker's start, then its reads.

use std::path::Path;

use assay_spec::assets;
use assay_spec::spec::{Format, parse_task};

const URDF: &str = r#"<robot name="thing"><link name="base"><visual><geometry><box size="0.05 0.05 0.05"/></geometry></visual></link></robot>"#;

#[test]
fn with_no_roots_given_the_working_folder_is_the_root() {
    let dir = tempfile::tempdir().unwrap();
    let (work, outside) = (dir.path().join("work"), dir.path().join("outside"));
    std::fs::create_dir_all(work.join("assets")).unwrap();
    std::fs::create_dir_all(&outside).unwrap();
    std::fs::write(work.join("assets/thing.urdf"), URDF).unwrap();
    std::fs::write(outside.join("thing.urdf"), URDF).unwrap();
    std::env::set_current_dir(&work).unwrap();

    assert_eq!(assets::roots(), None, "no worker yet: nothing set");
    let roots = assets::set_roots(&[]).unwrap();
    assert_eq!(roots, [work.canonicalize().unwrap()]);
    assert_eq!(assets::roots(), Some(roots.clone()));
    // The same roots again (a second worker in the process) are harmless; others are not.
    assets::set_roots(std::slice::from_ref(&work)).unwrap();
    let e = assets::set_roots(std::slice::from_ref(&outside)).unwrap_err();
    assert!(e.contains("already set"), "{e}");

    // Inside, by a relative or an absolute path.
    assert_eq!(
        assets::read_to_string(Path::new("assets/thing.urdf")).unwrap(),
        URDF
    );
    assert_eq!(
        assets::read_to_string(&work.join("assets/thing.urdf")).unwrap(),
        URDF
    );
    // Outside, by an absolute path, by climbing, and through a link inside the root.
    std::os::unix::fs::symlink(outside.join("thing.urdf"), work.join("assets/link.urdf")).unwrap();
    for p in [
        outside.join("thing.urdf"),
        Path::new("../outside/thing.urdf").to_owned(),
        work.join("assets/../../outside/thing.urdf"),
        work.join("assets/link.urdf"),
    ] {
        let e = assets::read(&p).unwrap_err();
        assert!(
            e.contains("outside the asset roots the operator allowed"),
            "{}: {e}",
            p.display()
        );
    }

    // A task whose own asset root is outside: refused naming the field, and its URDF, read
    // as the sim and render roles read it, is not opened.
    let mut spec = parse_task(
        assay_testkit::tasks::PUT_BLOCK_IN_ZONE,
        Format::Yaml,
        "t.yaml",
    )
    .unwrap();
    spec.source.asset_root = Some(outside.display().to_string());
    spec.scene.objects[0].shape = assay_spec::spec::Shape::Urdf {
        path: "thing.urdf".into(),
        joints: Default::default(),
        articulated: false,
        fill: Default::default(),
    };
    let (field, reason) = spec.check_asset_roots(&roots).unwrap_err();
    assert_eq!(field, "source.asset_root");
    assert!(
        reason.contains("outside the folders the operator allowed"),
        "{reason}"
    );
    let e = spec.resolve_asset("thing.urdf").unwrap_err();
    assert!(e.contains("outside the asset roots"), "{e}");
    let e = assay_spec::urdf::assemble_filled(
        &outside.join("thing.urdf"),
        &Default::default(),
        &Default::default(),
        &Default::default(),
    )
    .unwrap_err();
    assert!(e.contains("outside the asset roots"), "{e}");
    // Narrowed to a folder inside the working folder, it reads.
    spec.source.asset_root = Some(work.join("assets").display().to_string());
    spec.check_asset_roots(&roots).unwrap();
    assert!(spec.resolve_asset("thing.urdf").is_ok());
}
