//! The worker's roles in one process, without a coordinator: shards as the coordinator would
//! assign them, run through the same handler `assay worker` serves.

use std::path::Path;

use assay_model::episode::EpisodeOutcome;
use assay_proto::v1 as pb;
use assay_spec::spec::{Format, parse_task};
use assay_worker::{Options, Roles, Worker};
use assay_worker_runtime::ShardHandler;

fn example(rel: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../examples/tasks")
        .join(rel);
    let text = std::fs::read_to_string(&path).unwrap();
    parse_task(&text, Format::Yaml, &path.display().to_string())
        .unwrap()
        .canonical_json()
}

fn roles(names: &[&str], rt: &tokio::runtime::Runtime) -> Roles {
    Worker::new(Options {
        roles: names.iter().map(|r| (*r).to_owned()).collect(),
        worker_id: Some("test/1".into()),
        node_id: Some("test".into()),
        ..Options::default()
    })
    .unwrap()
    .into_roles(rt.handle().clone())
}

fn sim_shard(spec_json: String, seed: u64, policy: &str) -> pb::Assignment {
    pb::Assignment {
        lease_id: 1,
        shard_id: 7,
        batch_id: "b".into(),
        role: pb::Role::Sim as i32,
        task_spec_json: spec_json,
        seed,
        policy: Some(pb::PolicyRef {
            name: policy.into(),
        }),
        ..Default::default()
    }
}

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .unwrap()
}

#[test]
fn the_sim_role_runs_an_oracle_episode_and_stores_its_file() {
    let rt = runtime();
    let roles = roles(&["sim"], &rt);
    let root = tempfile::tempdir().unwrap();
    let spec = example("stacking/build-two-block-tower.yaml");
    let json = roles.run(&sim_shard(spec.clone(), 0, "oracle"), root.path());
    let outcome: EpisodeOutcome = serde_json::from_str(&json.unwrap()).unwrap();
    assert!(outcome.success, "{outcome:?}");
    assert_eq!(outcome.seed, 0);
    assert!(outcome.imagery.is_none(), "no render role, no imagery");
    // The episode file is in the artifact store under its content address.
    let file = root.path().join(&outcome.artifact);
    assert!(file.is_file(), "{}", file.display());
    assert_eq!(
        roles
            .counters()
            .episodes
            .load(std::sync::atomic::Ordering::Relaxed),
        1
    );
    // The same shard again gives the same episode, byte for byte.
    let again: EpisodeOutcome = serde_json::from_str(
        &roles
            .run(&sim_shard(spec, 0, "oracle"), root.path())
            .unwrap(),
    )
    .unwrap();
    assert_eq!(again.artifact, outcome.artifact);
}

#[test]
fn shards_a_role_cannot_run_fail_for_good_and_say_why() {
    let rt = runtime();
    let roles = roles(&["sim"], &rt);
    let root = tempfile::tempdir().unwrap();
    // A judge shard on a worker without the judge role.
    let judge = pb::Assignment {
        role: pb::Role::Judge as i32,
        ..sim_shard(example("stacking/build-two-block-tower.yaml"), 0, "oracle")
    };
    let e = roles.run(&judge, root.path()).unwrap_err();
    assert!(!e.retryable);
    assert!(
        e.message.contains("does not hold the role"),
        "{}",
        e.message
    );
    // A spec that does not parse.
    let e = roles
        .run(&sim_shard("{not json".into(), 0, "oracle"), root.path())
        .unwrap_err();
    assert!(!e.retryable);
    assert!(e.message.contains("does not parse"), "{}", e.message);
    // A policy name nobody knows names the task.
    let spec = example("stacking/build-two-block-tower.yaml");
    let e = roles
        .run(&sim_shard(spec, 0, "nonsense:x=1"), root.path())
        .unwrap_err();
    assert!(!e.retryable);
    assert!(e.message.contains("build-two-block-tower"), "{}", e.message);
    assert_eq!(
        roles
            .counters()
            .failed
            .load(std::sync::atomic::Ordering::Relaxed),
        2
    );
}

#[test]
fn unknown_roles_are_refused_before_any_connection() {
    let bad = |roles: &[&str]| {
        Worker::new(Options {
            roles: roles.iter().map(|r| (*r).to_owned()).collect(),
            ..Options::default()
        })
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default()
    };
    assert!(bad(&["painter"]).contains("unknown role 'painter'"));
}

#[test]
fn a_render_worker_draws_what_a_sim_only_worker_simulated_as_a_sim_render_worker_would() {
    let rt = runtime();
    let root = tempfile::tempdir().unwrap();
    let spec = example("stacking/bbsea-stack-green-cube-on-red-cube.yaml");
    let mut shard = sim_shard(spec.clone(), 3, "oracle");
    shard.render = true;
    // In one process.
    let both = roles(&["sim", "render"], &rt);
    let whole: EpisodeOutcome =
        serde_json::from_str(&both.run(&shard, root.path()).unwrap()).unwrap();
    assert!(whole.scenes.is_none());
    let imagery = whole
        .imagery
        .clone()
        .expect("pictures drawn in the process");
    // Apart: the sim-only worker returns the scenes, the render worker draws from them.
    let sim = roles(&["sim"], &rt);
    let simulated: EpisodeOutcome =
        serde_json::from_str(&sim.run(&shard, root.path()).unwrap()).unwrap();
    assert!(simulated.imagery.is_none());
    assert!(
        simulated.scenes.is_some(),
        "the scenes travel to a render worker"
    );
    let render = roles(&["render"], &rt);
    let mut render_shard = shard.clone();
    render_shard.role = pb::Role::Render as i32;
    render_shard.input_json = serde_json::to_string(&simulated).unwrap();
    let drawn: EpisodeOutcome =
        serde_json::from_str(&render.run(&render_shard, root.path()).unwrap()).unwrap();
    assert_eq!(
        drawn, whole,
        "the same episode and the same pictures, byte for byte"
    );
    assert_eq!(drawn.imagery.unwrap(), imagery);
    // A render-only worker runs no episode.
    let err = render.run(&shard, root.path()).unwrap_err();
    assert!(err.to_string().contains("does not hold the role"), "{err}");
    // Without the render flag, no pictures are asked for and none are drawn.
    shard.render = false;
    let plain: EpisodeOutcome =
        serde_json::from_str(&both.run(&shard, root.path()).unwrap()).unwrap();
    assert!(plain.imagery.is_none() && plain.scenes.is_none());
}
