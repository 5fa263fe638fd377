//! The store's tests of leasing by capability: what a shard needs, what a worker offers, and an
//! episode simulated without a renderer waiting for one.

use super::*;

/// An episode simulated where no renderer is: its scenes, as a sim-only worker returns them.
fn awaiting_pictures(l: &Lease) -> String {
    let mut e = episode(l);
    let scene = assay_spec::scene::SceneSnapshot {
        surface: assay_spec::spec::Surface::Table,
        objects: vec![],
        tool: None,
        tool_rotation: None,
        fingers: vec![],
        arm: vec![],
    };
    e.scenes = Some(assay_model::episode::EpisodeScenes {
        initial: scene.clone(),
        initial_step: 10,
        keyframes: vec![(20, scene)],
        keyframe_goals: vec![0],
        video: vec![],
        clip: None,
    });
    serde_json::to_string(&e).unwrap()
}

#[test]
fn an_episode_simulated_without_a_renderer_waits_for_a_render_worker_then_is_judged() {
    let mut s = Store::open_in_memory().unwrap();
    let mut b = batch(&["a"], &[1], 3);
    b.render = true;
    b.judges = vec!["offline".into()];
    let (id, _) = s.submit(&b, 0).unwrap();
    let l = s.lease("sim-only", &sim(), 5, 1, TTL).unwrap().remove(0);
    assert!(l.render, "a rendering batch asks for the pictures");
    let (ok, changed) = s
        .complete(
            "sim-only",
            l.lease_id,
            l.shard_id,
            &awaiting_pictures(&l),
            0.5,
            2,
        )
        .unwrap();
    assert!(ok);
    assert_eq!(changed.requeued, 1, "render workers are woken");
    let c = s.counts(&id).unwrap();
    assert_eq!((c.total, c.done, c.queued, c.judge_total), (1, 0, 1, 0));
    assert_eq!(
        c.state, "running",
        "the episode is not done without its pictures"
    );
    assert!(s.lease("sim-only", &sim(), 5, 3, TTL).unwrap().is_empty());
    assert_eq!(
        s.queued_needs(Some(&id)).unwrap(),
        vec![(vec!["render".to_owned()], 1)]
    );
    let render: Vec<String> = vec!["render".into()];
    // A render worker takes it with its scenes; it dies (its lease expires) and another one
    // renders it: nothing is lost, and the expired one's late result is not counted.
    let r1 = s.lease("r1", &render, 5, 4, TTL).unwrap().remove(0);
    assert_eq!(r1.role, "render");
    assert_eq!(
        r1.render_input.as_deref(),
        Some(awaiting_pictures(&l).as_str())
    );
    s.expire(4 + TTL + 1, None).unwrap();
    let r2 = s
        .lease("r2", &render, 5, 4 + TTL + 2, TTL)
        .unwrap()
        .remove(0);
    assert_eq!((r2.shard_id, r2.attempt), (l.shard_id, 2));
    let (late, _) = s
        .complete(
            "r1",
            r1.lease_id,
            r1.shard_id,
            &rendered(&l),
            0.1,
            4 + TTL + 3,
        )
        .unwrap();
    assert!(!late);
    let (ok, changed) = s
        .complete(
            "r2",
            r2.lease_id,
            r2.shard_id,
            &rendered(&l),
            0.25,
            4 + TTL + 3,
        )
        .unwrap();
    assert!(ok);
    assert_eq!(changed.requeued, 1, "one judge shard");
    let c = s.counts(&id).unwrap();
    assert_eq!((c.done, c.queued, c.judge_total), (1, 0, 1));
    let report = s.report(&id).unwrap();
    assert!(report.results.tasks[0].episodes[0].imagery.is_some());
    assert_eq!(
        report.run.workers,
        vec!["sim-only"],
        "the episode is the simulator's"
    );
    let judge: Vec<String> = vec!["judge".into(), "judge:offline".into()];
    let j = s.lease("j", &judge, 5, 4 + TTL + 4, TTL).unwrap().remove(0);
    assert_eq!(j.judge.unwrap().episode_json, rendered(&l));
}

#[test]
fn episodes_of_a_policy_that_sees_need_a_renderer_beside_the_simulator() {
    let mut s = Store::open_in_memory().unwrap();
    let mut b = batch(&["a"], &[1], 3);
    b.policies = vec!["oracle".into(), "oracle:sense=camera".into()];
    let (id, _) = s.submit(&b, 0).unwrap();
    let leases = s.lease("sim-only", &sim(), 5, 1, TTL).unwrap();
    assert_eq!(leases.len(), 1);
    assert_eq!(leases[0].policy, "oracle");
    assert_eq!(
        s.queued_needs(Some(&id)).unwrap(),
        vec![(vec!["sim".to_owned(), "render".to_owned()], 1)]
    );
    let both: Vec<String> = vec!["sim".into(), "render".into()];
    let l = s.lease("w", &both, 5, 2, TTL).unwrap().remove(0);
    assert_eq!(l.policy, "oracle:sense=camera");
}
