//! TorchScript policies (feature `torch`). The modules are traced from Rust with
//! `tch::CModule::create_by_tracing` and saved to a temporary folder, so the tests need neither
//! Python nor committed fixtures.
#![cfg(feature = "torch")]

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use assay_model::policy::{EpisodeContext, Policy, PolicyError, PolicyObservation, PolicySpec};
use assay_policy::torchscript::TorchScriptPolicy;
use tch::{CModule, Device, Kind, Tensor};

/// The policy: a chunk of two actions, [mean R, mean G, mean B, x] and 2·proprio − 1.
fn policy_fn(image: &Tensor, proprio: &Tensor) -> Tensor {
    let means = image.mean_dim([2i64, 3].as_slice(), false, Kind::Float); // [1, 3]
    let first = Tensor::cat(&[means, proprio.narrow(1, 0, 1)], 1); // [1, 4]
    let second = proprio * 2.0 - 1.0; // [1, 4]
    Tensor::stack(&[first, second], 1) // [1, 2, 4]
}

/// Traces `f` on inputs of the calling convention's shapes and saves it as `name` in `dir`.
fn save_traced(dir: &Path, name: &str, f: fn(&Tensor, &Tensor) -> Tensor) -> std::path::PathBuf {
    let image = Tensor::rand([1, 3, 8, 8], (Kind::Float, Device::Cpu));
    let proprio = Tensor::rand([1, 4], (Kind::Float, Device::Cpu));
    let module = CModule::create_by_tracing("Policy", "forward", &[image, proprio], &mut |xs| {
        vec![f(&xs[0], &xs[1])]
    })
    .expect("trace");
    let path = dir.join(name);
    module.save(&path).expect("save");
    path
}

fn observation() -> PolicyObservation {
    let (w, h) = (8u32, 8u32);
    let rgb = (0..w * h * 3).map(|i| (i * 7 % 256) as u8).collect();
    PolicyObservation::legacy(5, w, h, rgb, [0.25, -0.5, 0.125, 1.0])
}

/// What the traced function gives for `obs`, computed directly.
fn expected(obs: &PolicyObservation) -> Vec<[f32; 4]> {
    let image = Tensor::from_slice(&obs.rgb)
        .view([1, obs.height as i64, obs.width as i64, 3])
        .permute([0, 3, 1, 2])
        .to_kind(Kind::Float)
        / 255.0;
    let proprio = Tensor::from_slice(&obs.proprio).view([1, 4]);
    let values: Vec<f32> = policy_fn(&image, &proprio).view([-1]).try_into().unwrap();
    values.chunks(4).map(|a| a.try_into().unwrap()).collect()
}

#[test]
fn a_traced_module_acts_as_the_function_it_traced() {
    let dir = tempfile::tempdir().unwrap();
    let path = save_traced(dir.path(), "policy.pt", policy_fn);
    let mut policy = TorchScriptPolicy::load(&path, Device::Cpu).unwrap();
    policy
        .reset(&EpisodeContext {
            task_id: "t".into(),
            seed: 1,
            instruction: String::new(),
            arm: None,
        })
        .unwrap();
    let obs = observation();
    let chunk = policy.act(&obs).unwrap();
    let want = expected(&obs);
    assert_eq!(chunk.len(), 2);
    for (got, want) in chunk.iter().zip(&want) {
        for (g, w) in got.iter().zip(want) {
            assert!((g - w).abs() < 1e-6, "{chunk:?} vs {want:?}");
        }
    }
    assert_eq!(chunk[1], [-0.5, -2.0, -0.75, 1.0]);

    // The same through the spec loader.
    let rt = tokio::runtime::Runtime::new().unwrap();
    let spec = PolicySpec::parse(&format!("torchscript:path={}", path.display())).unwrap();
    let mut loaded = assay_policy::load(&spec, dir.path(), rt.handle()).unwrap();
    assert_eq!(loaded.act(&obs).unwrap(), chunk);
}

#[test]
fn one_action_of_shape_1_4_is_a_chunk_of_one() {
    let dir = tempfile::tempdir().unwrap();
    let path = save_traced(dir.path(), "one.pt", |_, proprio| proprio * 3.0);
    let mut policy = TorchScriptPolicy::load(&path, Device::Cpu).unwrap();
    assert_eq!(
        policy.act(&observation()).unwrap(),
        vec![[0.75, -1.5, 0.375, 3.0]]
    );
}

#[test]
fn an_answer_of_the_wrong_shape_is_a_bad_answer_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = save_traced(dir.path(), "three.pt", |_, proprio| proprio.narrow(1, 0, 3));
    let mut policy = TorchScriptPolicy::load(&path, Device::Cpu).unwrap();
    match policy.act(&observation()) {
        Err(PolicyError::BadAnswer(m)) => assert!(m.contains("[1, 3]"), "{m}"),
        other => panic!("expected BadAnswer, got {other:?}"),
    }
}

#[test]
fn a_file_that_is_not_torchscript_cannot_be_loaded() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("notes.pt");
    std::fs::write(&path, "not a model").unwrap();
    match TorchScriptPolicy::load(&path, Device::Cpu) {
        Err(PolicyError::Load(m)) => assert!(m.contains(&path.display().to_string()), "{m}"),
        other => panic!("expected Load, got {other:?}"),
    }
    let missing = dir.path().join("missing.pt");
    match TorchScriptPolicy::load(&missing, Device::Cpu) {
        Err(PolicyError::Load(m)) => assert!(m.contains("missing.pt"), "{m}"),
        other => panic!("expected Load, got {other:?}"),
    }
}

#[test]
fn a_torchscript_policy_served_over_grpc() {
    let dir = tempfile::tempdir().unwrap();
    let path = save_traced(dir.path(), "policy.pt", policy_fn);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let spec = PolicySpec::TorchScript {
        path: path.display().to_string(),
        interface: None,
    };
    let factory = assay_policy::factory(&spec, dir.path(), rt.handle(), None).unwrap();
    let listener = rt
        .block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))
        .unwrap();
    let url = format!("http://{}", listener.local_addr().unwrap());
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let server = rt.spawn(assay_policy::serve(
        listener,
        Arc::clone(&factory),
        assay_policy::ServerInfo::default(),
        None,
        async {
            let _ = stopped.await;
        },
    ));
    let mut remote =
        assay_policy::RemotePolicy::connect(&url, Duration::from_secs(5), rt.handle().clone())
            .unwrap();
    remote
        .reset(&EpisodeContext {
            task_id: "t".into(),
            seed: 1,
            instruction: String::new(),
            arm: None,
        })
        .unwrap();
    let obs = observation();
    let mut local = TorchScriptPolicy::load(&path, Device::Cpu).unwrap();
    assert_eq!(remote.act(&obs).unwrap(), local.act(&obs).unwrap());
    drop(remote);
    let _ = stop.send(());
    rt.block_on(server).unwrap().unwrap();
}
