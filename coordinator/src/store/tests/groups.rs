//! A ranking and a generalization scoped to some of the batch's task groups.

use assay_model::generalization::GeneralizationPlan;
use assay_model::proxy::{LadderPlan, ProxyConfig, RankingPlan};

use super::*;

/// With `groups` named, the proxy's world model, the ladder, its episodes and the proxy are
/// queued for the ranked group only and the generalization policy for its own group only; the
/// other group's episodes count in the batch's tables as ever. The world model is fitted while
/// the ladder trains, and the proxy starts from it.
#[test]
fn a_ranking_and_a_generalization_scoped_to_groups_leave_the_others_alone() {
    let mut s = Store::open_in_memory().unwrap();
    let mut b = batch(&["a", "b"], &[0, 1], 3);
    b.tasks[0].spec_json = r#"{"id": "a"}"#.into();
    b.tasks[1].spec_json = r#"{"id": "b"}"#.into();
    b.tasks[1].info.group = "h".into();
    b.policies = vec!["oracle".into(), "oracle:noise=0.01".into()];
    b.ranking = Some(RankingPlan {
        train_policies: b.policies.clone(),
        config: ProxyConfig::default(),
        ladder: Some(LadderPlan {
            episodes: vec![2],
            checkpoints: vec![5],
            max_steps: 600,
            ..LadderPlan::default()
        }),
        groups: vec!["g".into()],
    });
    b.generalization = Some(GeneralizationPlan {
        episodes: 2,
        held_out_seeds: 1,
        groups: vec!["h".into()],
        ..GeneralizationPlan::default()
    });
    let (id, n) = s.submit(&b, 0).unwrap();
    assert_eq!(n, 8);
    let leases = s.lease("w", &sim(), 8, 1, TTL).unwrap();
    for (i, l) in leases.iter().enumerate() {
        finish_episode(&mut s, l, i % 2 == 0, &format!("clips/{i}.clip"));
    }
    let trainer = vec!["trainer".to_owned()];
    let queued = s.lease("t", &trainer, 10, 3, TTL).unwrap();
    let jobs = trainer_jobs(&queued);
    assert_eq!(jobs.len(), 3, "{jobs:?}");
    // First the proxy's world model of the ranked group, fitted on the training policies'
    // episodes while the ladder trains; then the ladder; then the generalization policy.
    let TrainerJob::ProxyWorld { group, train, .. } = &jobs[0] else {
        panic!("{:?}", jobs[0])
    };
    assert_eq!(group, "g");
    assert_eq!(train.len(), 4);
    assert!(
        train
            .iter()
            .all(|e| e.task_id == "a" && e.success.is_some())
    );
    let world = &queued[0];
    let mut ladder = None;
    for (l, job) in queued.iter().zip(&jobs).skip(1) {
        let TrainerJob::Diffusion {
            group, checkpoints, ..
        } = job
        else {
            panic!("{job:?}")
        };
        match group.as_str() {
            "g" => {
                assert_eq!(checkpoints, &vec![5], "the ladder, in the ranked group");
                ladder = Some(l);
            }
            "h" => assert!(checkpoints.is_empty(), "the generalization policy"),
            other => panic!("a job for group {other}"),
        }
    }
    let l = ladder.expect("a ladder training in group g");
    let done = diffusion_done("policies/m.diffusion", &[]);
    let (ok, changed) = s
        .complete("t", l.lease_id, l.shard_id, &done, 1.0, 4)
        .unwrap();
    assert!(ok);
    // The ladder's policy runs the ranked group's one task on its 2 seeds, never task b.
    assert_eq!(changed.requeued, 2);
    let sim_render: Vec<String> = ["sim", "render"].map(String::from).to_vec();
    let episodes = s.lease("w", &sim_render, 20, 5, TTL).unwrap();
    assert_eq!(episodes.len(), 2);
    for (i, l) in episodes.iter().enumerate() {
        let spec: serde_json::Value = serde_json::from_str(&l.task_spec_json).unwrap();
        assert_eq!(spec["id"], "a");
        finish_episode(&mut s, l, false, &format!("clips/l{i}.clip"));
    }
    // The ladder is done, but its world model is still being fitted: the proxy waits for it.
    assert!(s.lease("t", &trainer, 10, 6, TTL).unwrap().is_empty());
    let done = proxy_world_done("checkpoints/b/world-1.ckpt");
    assert!(
        s.complete("t", world.lease_id, world.shard_id, &done, 1.0, 7)
            .unwrap()
            .0
    );
    // One proxy, for group g, starting from that world model; none for h.
    let queued = s.lease("t", &trainer, 10, 8, TTL).unwrap();
    let jobs = trainer_jobs(&queued);
    assert_eq!(jobs.len(), 1, "{jobs:?}");
    let TrainerJob::Proxy {
        group,
        train: proxy_train,
        eval,
        world_model,
        ..
    } = &jobs[0]
    else {
        panic!("{:?}", jobs[0])
    };
    assert_eq!(group, "g");
    assert_eq!(
        proxy_train, train,
        "the world model's training episodes, exactly"
    );
    assert!(eval.iter().all(|e| e.task_id == "a"));
    assert_eq!(eval.len(), 2);
    assert_eq!(world_model.as_deref(), Some("checkpoints/b/world-1.ckpt"));
    // Every policy's episodes of both groups are the batch's.
    let r = s.report(&id).unwrap().results;
    let oracle = r.by_policy.iter().find(|p| p.policy == "oracle").unwrap();
    assert_eq!(oracle.success.trials, 4);
}
