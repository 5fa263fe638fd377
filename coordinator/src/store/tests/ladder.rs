//! The ranking's ladder of learned policies: its families, its training, its episodes and
//! its proxy.

use super::*;
use assay_model::proxy::{LadderPlan, ProxyConfig};

/// A ladder of two families trains every run once per family, each with its own backbone and
/// the same clips and checkpoints; the world model fitted ahead takes only the episodes of
/// `world_model_policies`.
#[test]
fn a_ladder_of_two_families_trains_each_run_in_each() {
    use assay_model::diffusion::Backbone;
    let mut s = Store::open_in_memory().unwrap();
    let mut b = batch(&["a"], &[0, 1, 2, 3], 3);
    b.tasks[0].spec_json = r#"{"id": "a"}"#.into();
    b.policies = vec!["oracle".into(), "oracle:noise=0.05".into()];
    b.ranking = Some(RankingPlan {
        train_policies: b.policies.clone(),
        // The world model without rollouts: the oracle's episodes alone train it.
        config: ProxyConfig {
            world_model_policies: vec!["oracle".into()],
            ..ProxyConfig::default()
        },
        ladder: Some(LadderPlan {
            episodes: vec![2, 4],
            checkpoints: vec![3, 6],
            backbones: vec![Backbone::Transformer, Backbone::Unet, Backbone::Transformer],
            ..LadderPlan::default()
        }),
        groups: Vec::new(),
    });
    s.submit(&b, 0).unwrap();
    for (i, l) in s.lease("w", &sim(), 8, 1, TTL).unwrap().iter().enumerate() {
        finish_episode(&mut s, l, true, &format!("clips/{i}.clip"));
    }
    let trainer = vec!["trainer".to_owned()];
    let queued = s.lease("t", &trainer, 10, 3, TTL).unwrap();
    let world: Vec<String> = trainer_jobs(&queued)
        .into_iter()
        .find_map(|job| match job {
            TrainerJob::ProxyWorld { train, .. } => {
                Some(train.into_iter().map(|e| e.policy).collect())
            }
            _ => None,
        })
        .expect("the proxy's world model, fitted ahead");
    assert_eq!(
        world, ["oracle"; 4],
        "the world model's clips: the oracle's only"
    );
    let mut runs: Vec<(Backbone, usize, Vec<u64>)> = trainer_jobs(&queued)
        .into_iter()
        .filter_map(|job| match job {
            TrainerJob::Diffusion {
                clips,
                config,
                checkpoints,
                ..
            } => Some((config.backbone, clips.len(), checkpoints)),
            _ => None,
        })
        .collect();
    runs.sort_by_key(|r| (r.0.as_str(), r.1));
    assert_eq!(
        runs,
        [
            (Backbone::Transformer, 2, vec![3, 6]),
            (Backbone::Transformer, 4, vec![3, 6]),
            (Backbone::Unet, 2, vec![3, 6]),
            (Backbone::Unet, 4, vec![3, 6]),
        ]
    );
}

/// Which ladder training finishes first changes neither the proxy's ranked episodes nor their
/// order (the action test pairs each with the next): each training's episodes come in the order
/// the trainings were planned, the U-Net's before the transformer's here.
#[test]
fn the_proxy_s_episodes_keep_the_trainings_planned_order_whichever_finishes_first() {
    use assay_model::diffusion::Backbone;
    let ranked = |transformer_first: bool| -> Vec<(String, u64)> {
        let mut s = Store::open_in_memory().unwrap();
        let mut b = batch(&["a"], &[0, 1], 3);
        b.tasks[0].spec_json = r#"{"id": "a"}"#.into();
        b.policies = vec!["oracle".into(), "oracle:noise=0.05".into()];
        b.ranking = Some(RankingPlan {
            train_policies: b.policies.clone(),
            config: ProxyConfig::default(),
            ladder: Some(LadderPlan {
                episodes: vec![2],
                checkpoints: vec![3],
                backbones: vec![Backbone::Unet, Backbone::Transformer],
                ..LadderPlan::default()
            }),
            groups: Vec::new(),
        });
        s.submit(&b, 0).unwrap();
        for (i, l) in s.lease("w", &sim(), 8, 1, TTL).unwrap().iter().enumerate() {
            finish_episode(&mut s, l, i % 2 == 0, &format!("clips/{i}.clip"));
        }
        let trainer = vec!["trainer".to_owned()];
        let queued = s.lease("t", &trainer, 10, 3, TTL).unwrap();
        let mut trainings = Vec::new();
        for (l, job) in queued.iter().zip(trainer_jobs(&queued)) {
            match job {
                TrainerJob::Diffusion { config, .. } => trainings.push((l, config.backbone)),
                // The world model fitted ahead fails: the proxy fits its own.
                _ => {
                    s.fail(l.lease_id, l.shard_id, "no space left", false, 4)
                        .unwrap();
                }
            }
        }
        assert_eq!(trainings.len(), 2);
        if transformer_first {
            trainings.reverse();
        }
        for (l, backbone) in trainings {
            let name = backbone.as_str();
            let done = diffusion_done(
                &format!("policies/{name}.diffusion"),
                &[(3, &format!("policies/{name}3.diffusion"))],
            );
            let mut outcome: TrainerOutcome = serde_json::from_str(&done).unwrap();
            if let TrainerOutcome::Diffusion { fit, .. } = &mut outcome {
                fit.config.backbone = backbone;
            }
            let done = serde_json::to_string(&outcome).unwrap();
            assert!(
                s.complete("t", l.lease_id, l.shard_id, &done, 1.0, 5)
                    .unwrap()
                    .0
            );
        }
        let sim_render: Vec<String> = ["sim", "render"].map(String::from).to_vec();
        let episodes = s.lease("w", &sim_render, 20, 6, TTL).unwrap();
        assert_eq!(episodes.len(), 8, "2 policies of each training x 2 seeds");
        for (i, l) in episodes.iter().enumerate() {
            finish_episode(&mut s, l, false, &format!("clips/l{i}.clip"));
        }
        let queued = s.lease("t", &trainer, 10, 7, TTL).unwrap();
        assert_eq!(queued.len(), 1);
        let job = serde_json::from_str(queued[0].trainer_job.as_deref().unwrap()).unwrap();
        let TrainerJob::Proxy { eval, .. } = job else {
            panic!("{job:?}")
        };
        eval.into_iter().map(|e| (e.policy, e.seed)).collect()
    };
    let planned = ranked(false);
    assert_eq!(planned.len(), 8);
    assert!(
        planned[..4].iter().all(|(p, _)| p.contains("/unet")),
        "{planned:?}"
    );
    assert_eq!(ranked(true), planned);
}

/// A ranking batch whose policies all train the world model ranks a ladder of learned
/// policies instead: trained once the group's episodes are done, on the ladder policy's first
/// clips; each kept policy runs every (task, seed) of the group as an ordinary episode; the
/// proxy waits for them (a failed training does not block it) and ranks them with each
/// episode's step budget. A generalization policy of the same batch stays apart.
#[test]
fn a_ladder_of_learned_policies_is_trained_then_run_then_ranked() {
    use assay_model::generalization::GeneralizationPlan;
    use assay_model::proxy::ProxyPrediction;
    let mut s = Store::open_in_memory().unwrap();
    let mut b = batch(&["a", "b"], &[0, 1], 3);
    // Task a's budget is its own, 400 steps; b has the default.
    b.tasks[0].spec_json = r#"{"id": "a", "physics": {"max_steps": 400}}"#.into();
    b.tasks[1].spec_json = r#"{"id": "b"}"#.into();
    b.policies = vec!["oracle".into(), "oracle:noise=0.01".into()];
    b.ranking = Some(RankingPlan {
        train_policies: b.policies.clone(),
        config: ProxyConfig::default(),
        ladder: Some(LadderPlan {
            train_policy: "oracle".into(),
            episodes: vec![4, 2, 8],
            checkpoints: vec![5, 2, 5],
            max_steps: 600,
            ..LadderPlan::default()
        }),
        groups: Vec::new(),
    });
    b.generalization = Some(GeneralizationPlan {
        episodes: 2,
        held_out_seeds: 1,
        ..GeneralizationPlan::default()
    });
    let (id, n) = s.submit(&b, 0).unwrap();
    assert_eq!(n, 8);
    let trainer = vec!["trainer".to_owned()];
    let leases = s.lease("w", &sim(), 8, 1, TTL).unwrap();
    for (i, l) in leases.iter().enumerate() {
        finish_episode(&mut s, l, i % 2 == 0, &format!("clips/{i}.clip"));
        if i + 1 < leases.len() {
            assert!(s.lease("t", &trainer, 10, 2, TTL).unwrap().is_empty());
        }
    }
    // One training per run; 4 clips of the oracle cover the run of 8, which is left out. The
    // generalization policy is queued as before. No proxy yet.
    let queued = s.lease("t", &trainer, 10, 3, TTL).unwrap();
    let oracle_clips: Vec<String> = (0..8)
        .filter(|i| leases[*i].policy == "oracle")
        .map(|i| format!("clips/{i}.clip"))
        .collect();
    let mut ladder = Vec::new();
    let mut general = None;
    let mut world = None;
    for (l, job) in queued.iter().zip(trainer_jobs(&queued)) {
        if let TrainerJob::ProxyWorld { train, .. } = &job {
            assert_eq!(train.len(), 8);
            world = Some(l);
            continue;
        }
        let TrainerJob::Diffusion {
            group,
            clips,
            config,
            checkpoints,
        } = job
        else {
            panic!("{job:?}")
        };
        assert_eq!(group, "g");
        if checkpoints.is_empty() {
            assert_eq!(clips, oracle_clips[..2]);
            general = Some(l);
        } else {
            assert_eq!((config.steps, checkpoints), (5, vec![2, 5]));
            ladder.push((l, clips));
        }
    }
    assert_eq!(ladder.len(), 2);
    // The proxy's world model, fitted ahead, fails: reported, and the proxy fits its own.
    let world = world.expect("the proxy's world model, fitted ahead");
    s.fail(world.lease_id, world.shard_id, "no space left", false, 4)
        .unwrap();
    assert_eq!(ladder[0].1, oracle_clips[..2]);
    assert_eq!(ladder[1].1, oracle_clips);
    let general = general.expect("a generalization training");
    let done = diffusion_done("policies/g.diffusion", &[]);
    let (ok, changed) = s
        .complete("t", general.lease_id, general.shard_id, &done, 1.0, 4)
        .unwrap();
    assert!(ok);
    assert_eq!(changed.requeued, 4, "2 trained variations, 2 held-out");
    // The first run's policies (a checkpoint named twice, and the final one) run the group's
    // 2 tasks × 2 seeds each, in the same transaction.
    let (l2, _) = &ladder[0];
    let done = diffusion_done(
        "policies/m2.diffusion",
        &[(2, "policies/c2.diffusion"), (3, "policies/c2.diffusion")],
    );
    let (ok, changed) = s
        .complete("t", l2.lease_id, l2.shard_id, &done, 1.0, 5)
        .unwrap();
    assert!(ok);
    assert_eq!(changed.requeued, 8);
    // The second run fails: reported, and the proxy does not wait for it.
    let (l4, _) = &ladder[1];
    s.fail(l4.lease_id, l4.shard_id, "out of memory", false, 6)
        .unwrap();
    assert!(s.lease("t", &trainer, 10, 6, TTL).unwrap().is_empty());
    let learned = [
        "diffusion:model=policies/c2.diffusion,max_steps=600",
        "diffusion:model=policies/m2.diffusion,max_steps=600",
    ];
    // Learned policies see while they run: their episodes need a renderer beside the simulator.
    assert!(s.lease("w", &sim(), 20, 7, TTL).unwrap().is_empty());
    let sim_render: Vec<String> = ["sim", "render"].map(String::from).to_vec();
    let episodes = s.lease("w", &sim_render, 20, 7, TTL).unwrap();
    assert_eq!(episodes.len(), 12);
    let mut ranked: Vec<(String, String, u64)> = Vec::new();
    for (i, l) in episodes.iter().enumerate() {
        assert_eq!((l.role.as_str(), l.clip_size), ("sim", 64));
        if !l.policy.contains("/g.diffusion") {
            let spec: serde_json::Value = serde_json::from_str(&l.task_spec_json).unwrap();
            let task = spec["id"].as_str().unwrap().to_owned();
            ranked.push((l.policy.clone(), task, l.seed));
        }
        // The proxy waits for the last of them.
        assert!(s.lease("t", &trainer, 10, 7, TTL).unwrap().is_empty());
        finish_episode(
            &mut s,
            l,
            l.policy == learned[1],
            &format!("clips/l{i}.clip"),
        );
    }
    ranked.sort();
    let mut want: Vec<(String, String, u64)> = Vec::new();
    for p in learned {
        for t in ["a", "b"] {
            for seed in [0, 1] {
                want.push((p.to_owned(), t.to_owned(), seed));
            }
        }
    }
    assert_eq!(ranked, want);
    let queued = s.lease("t", &trainer, 10, 8, TTL).unwrap();
    assert_eq!(queued.len(), 1);
    let input = queued[0].trainer_job.clone().unwrap();
    let TrainerJob::Proxy {
        train,
        eval,
        world_model,
        ..
    } = serde_json::from_str(&input).unwrap()
    else {
        panic!("{input}")
    };
    assert_eq!(world_model, None);
    // Trained on the batch's 8 episodes, ranking the ladder's 8, never the generalization's.
    assert_eq!(train.len(), 8);
    assert_eq!(eval.len(), 8);
    assert_eq!(input.matches("\"success\"").count(), 8);
    assert!(eval.iter().all(|e| learned.contains(&e.policy.as_str())));
    // Each ranked episode names its ladder family (the cross-family ablation groups by it); a
    // training episode names none.
    assert!(eval.iter().all(|e| e.family == "unet"), "{eval:?}");
    assert!(train.iter().all(|e| e.family.is_empty()));
    // Budgets: the task's, or the policy's horizon when smaller.
    for e in train.iter().chain(&eval) {
        let want = match (e.task_id.as_str(), eval.contains(e)) {
            ("a", _) => 400,
            (_, true) => 600,
            _ => 20_000,
        };
        assert_eq!(e.budget_steps, want, "{e:?}");
    }
    let predictions = eval
        .iter()
        .map(|e| ProxyPrediction {
            imagined_frames: 3,
            ..prediction(e, e.policy == learned[1])
        })
        .collect();
    let l = &queued[0];
    let done = proxy_done(predictions);
    assert!(
        s.complete("t", l.lease_id, l.shard_id, &done, 1.0, 9)
            .unwrap()
            .0
    );
    assert_eq!(s.counts(&id).unwrap().state, "completed");
    let r = s.report(&id).unwrap().results;
    // The learned policies are the batch's: in its success tables and ranked.
    for p in learned {
        assert!(r.policies.iter().any(|q| q == p), "{:?}", r.policies);
        let row = r.by_policy.iter().find(|q| q.policy == p).unwrap();
        assert_eq!(row.success.trials, 4);
    }
    let k = r.ranking.unwrap();
    let mut ranked_policies = k.ranked_policies.clone();
    ranked_policies.sort();
    assert_eq!(ranked_policies, learned);
    // Each reads by what it was trained on and for how long: the run's 2 episodes, the step it
    // was kept at (the checkpoint named twice by its first, the final model by the fit's).
    assert_eq!(
        k.labels,
        [
            (learned[0].to_owned(), "diffusion 2 ep @ 2".to_owned()),
            (learned[1].to_owned(), "diffusion 2 ep @ 3000".to_owned()),
        ]
    );
    assert_eq!(k.rows.len(), 4);
    assert!(k.proxy_agreement.is_some_and(|a| a.successes == a.trials));
    assert_eq!(k.errors.len(), 2);
    assert!(
        k.errors
            .iter()
            .any(|e| e.1.starts_with("ladder g @ 4: out of memory")),
        "{:?}",
        k.errors
    );
    assert!(
        k.errors
            .iter()
            .any(|e| e.1 == "world model g: no space left"),
        "{:?}",
        k.errors
    );
    assert_eq!(r.generalization.unwrap().groups.len(), 1);
}

/// A ladder policy kept at a `train_checkpoints` step trains the proxy and is never ranked: the
/// run keeps it beside the ranked ones, it runs every (task, seed) of the group, and its
/// episodes (with their outcomes) join the training policies' — in the world model fitted
/// ahead, which waits for them, and in the proxy's training set — while only the other kept
/// policy is ranked and the report lists it among the training policies.
#[test]
fn a_ladder_s_training_only_policies_train_the_proxy_and_are_never_ranked() {
    let ladder = LadderPlan {
        episodes: vec![2],
        checkpoints: vec![3000],
        train_checkpoints: vec![2],
        max_steps: 600,
        ..LadderPlan::default()
    };
    let (mut s, id) = ladder_batch_run(&[0, 1], &ladder);
    // The ladder's training alone: the world model waits for the training-only policy's
    // episodes. The run is kept at both kinds of checkpoint.
    let trainer = vec!["trainer".to_owned()];
    let queued = s.lease("t", &trainer, 10, 2, TTL).unwrap();
    let jobs = trainer_jobs(&queued);
    assert_eq!(jobs.len(), 1, "{jobs:?}");
    let TrainerJob::Diffusion {
        config,
        checkpoints,
        ..
    } = &jobs[0]
    else {
        panic!("{:?}", jobs[0])
    };
    assert_eq!(
        (config.steps, checkpoints.as_slice()),
        (3000, &[2, 3000][..])
    );
    let done = diffusion_done("policies/m.diffusion", &[(2, "policies/c2.diffusion")]);
    let l = &queued[0];
    let (ok, changed) = s
        .complete("t", l.lease_id, l.shard_id, &done, 1.0, 3)
        .unwrap();
    assert!(ok);
    assert_eq!(changed.requeued, 4, "2 kept policies × 1 task × 2 seeds");
    let (training_only, ranked) = (
        ladder.policy_name("policies/c2.diffusion"),
        ladder.policy_name("policies/m.diffusion"),
    );
    let sim_render: Vec<String> = ["sim", "render"].map(String::from).to_vec();
    let episodes = s.lease("w", &sim_render, 20, 4, TTL).unwrap();
    assert_eq!(episodes.len(), 4);
    for (i, l) in episodes.iter().enumerate() {
        assert!(s.lease("t", &trainer, 10, 4, TTL).unwrap().is_empty());
        let success = l.policy == training_only && l.seed == 0;
        finish_episode(&mut s, l, success, &format!("clips/l{i}.clip"));
    }
    // Now the world model, on the batch's 4 episodes and the training-only policy's 2.
    let queued = s.lease("t", &trainer, 10, 5, TTL).unwrap();
    let jobs = trainer_jobs(&queued);
    assert_eq!(
        jobs.len(),
        1,
        "the proxy waits for its world model: {jobs:?}"
    );
    let TrainerJob::ProxyWorld { train, .. } = &jobs[0] else {
        panic!("{:?}", jobs[0])
    };
    let of = |p: &str| train.iter().filter(|e| e.policy == p).count();
    assert_eq!((train.len(), of(&training_only), of(&ranked)), (6, 2, 0));
    let queued = finish_world_lease_proxy(&mut s, &queued[0]);
    let jobs = trainer_jobs(&queued);
    let TrainerJob::Proxy {
        train: proxy_train,
        eval,
        ..
    } = &jobs[0]
    else {
        panic!("{:?}", jobs[0])
    };
    assert_eq!(
        proxy_train, train,
        "the world model's training episodes, exactly"
    );
    // The training-only policy's outcomes reach the proxy (it is not ranked); it has no family.
    let own: Vec<(u64, Option<bool>, &str)> = proxy_train
        .iter()
        .filter(|e| e.policy == training_only)
        .map(|e| (e.seed, e.success, e.family.as_str()))
        .collect();
    assert_eq!(own, [(0, Some(true), ""), (1, Some(false), "")]);
    assert_eq!(eval.len(), 2);
    assert!(
        eval.iter()
            .all(|e| e.policy == ranked && e.success.is_none() && e.family == "unet")
    );
    let k = finish_proxy_ranking_one(&mut s, &id, &queued[0], eval, &ranked, &training_only);
    assert!(
        k.labels
            .contains(&(training_only.clone(), "diffusion 2 ep @ 2".to_owned())),
        "{:?}",
        k.labels
    );
}

/// Every policy of a `train_episodes` run trains the proxy and is never ranked: both runs train,
/// the world model waits for the training-only run's episodes and learns them, and only the
/// ranked run's policy is imagined and ranked, the other listed among the training policies.
#[test]
fn a_training_only_run_trains_the_proxy_and_is_never_ranked() {
    let ladder = LadderPlan {
        episodes: vec![4],
        train_episodes: vec![2],
        checkpoints: vec![5],
        max_steps: 600,
        ..LadderPlan::default()
    };
    let (mut s, id) = ladder_batch_run(&[0, 1, 2, 3], &ladder);
    let trainer = vec!["trainer".to_owned()];
    let queued = s.lease("t", &trainer, 10, 2, TTL).unwrap();
    let jobs = trainer_jobs(&queued);
    let runs: Vec<usize> = jobs
        .iter()
        .map(|j| match j {
            TrainerJob::Diffusion { clips, .. } => clips.len(),
            other => panic!("the world model waits for the ladder: {other:?}"),
        })
        .collect();
    assert_eq!(runs, [2, 4]);
    let (small, big) = ("policies/small.diffusion", "policies/big.diffusion");
    for (l, (model, clips)) in queued.iter().zip([(small, 2), (big, 4)]) {
        let done = diffusion_done_on(model, &[], clips);
        assert!(
            s.complete("t", l.lease_id, l.shard_id, &done, 1.0, 3)
                .unwrap()
                .0
        );
    }
    let (training_only, ranked) = (ladder.policy_name(small), ladder.policy_name(big));
    let sim_render: Vec<String> = ["sim", "render"].map(String::from).to_vec();
    let episodes = s.lease("w", &sim_render, 20, 4, TTL).unwrap();
    assert_eq!(episodes.len(), 8, "2 runs × 1 task × 4 seeds");
    for (i, l) in episodes.iter().enumerate() {
        assert!(s.lease("t", &trainer, 10, 4, TTL).unwrap().is_empty());
        let success = l.policy == training_only && l.seed < 2;
        finish_episode(&mut s, l, success, &format!("clips/l{i}.clip"));
    }
    let queued = s.lease("t", &trainer, 10, 5, TTL).unwrap();
    let jobs = trainer_jobs(&queued);
    let [TrainerJob::ProxyWorld { train, .. }] = &jobs[..] else {
        panic!("{jobs:?}")
    };
    let of = |p: &str| train.iter().filter(|e| e.policy == p).count();
    assert_eq!((train.len(), of(&training_only), of(&ranked)), (12, 4, 0));
    let queued = finish_world_lease_proxy(&mut s, &queued[0]);
    let jobs = trainer_jobs(&queued);
    let [
        TrainerJob::Proxy {
            train: proxy_train,
            eval,
            ..
        },
    ] = &jobs[..]
    else {
        panic!("{jobs:?}")
    };
    assert_eq!(proxy_train, train);
    let outcomes: Vec<Option<bool>> = proxy_train
        .iter()
        .filter(|e| e.policy == training_only)
        .map(|e| e.success)
        .collect();
    assert_eq!(outcomes, [Some(true), Some(true), Some(false), Some(false)]);
    assert_eq!(eval.len(), 4);
    assert!(
        eval.iter()
            .all(|e| e.policy == ranked && e.success.is_none())
    );
    finish_proxy_ranking_one(&mut s, &id, &queued[0], eval, &ranked, &training_only);
}

/// A batch of one task `a` at `seeds` with the oracle and a noisier one, both training a proxy
/// with `ladder`, submitted and its episodes finished (every other one a success).
fn ladder_batch_run(seeds: &[u64], ladder: &LadderPlan) -> (Store, String) {
    let mut s = Store::open_in_memory().unwrap();
    let mut b = batch(&["a"], seeds, 3);
    b.tasks[0].spec_json = r#"{"id": "a"}"#.into();
    b.policies = vec!["oracle".into(), "oracle:noise=0.05".into()];
    b.ranking = Some(RankingPlan {
        train_policies: b.policies.clone(),
        config: ProxyConfig::default(),
        ladder: Some(ladder.clone()),
        groups: Vec::new(),
    });
    let (id, _) = s.submit(&b, 0).unwrap();
    for (i, l) in s.lease("w", &sim(), 8, 1, TTL).unwrap().iter().enumerate() {
        finish_episode(&mut s, l, i % 2 == 0, &format!("clips/{i}.clip"));
    }
    (s, id)
}

/// Completes the world model fitted ahead (leased as `world`) and leases what follows it.
fn finish_world_lease_proxy(s: &mut Store, world: &Lease) -> Vec<Lease> {
    let done = proxy_world_done("checkpoints/b/world-1.ckpt");
    let (ok, _) = s
        .complete("t", world.lease_id, world.shard_id, &done, 1.0, 6)
        .unwrap();
    assert!(ok);
    s.lease("t", &["trainer".to_owned()], 10, 7, TTL).unwrap()
}

/// Completes the proxy (leased as `proxy`) with a prediction per `eval` episode and returns the
/// report's ranking, having checked that it ranks `ranked` alone and lists `training_only` among
/// the training policies, never in its rows.
fn finish_proxy_ranking_one(
    s: &mut Store,
    id: &str,
    proxy: &Lease,
    eval: &[assay_model::proxy::ProxyEpisode],
    ranked: &str,
    training_only: &str,
) -> assay_report::ranking::RankingResults {
    let predictions = eval.iter().map(|e| prediction(e, false)).collect();
    let done = proxy_done(predictions);
    let (ok, _) = s
        .complete("t", proxy.lease_id, proxy.shard_id, &done, 1.0, 8)
        .unwrap();
    assert!(ok);
    let k = s.report(id).unwrap().results.ranking.unwrap();
    assert_eq!(k.ranked_policies, [ranked]);
    assert!(
        k.train_policies.iter().any(|p| p == training_only),
        "{:?}",
        k.train_policies
    );
    assert!(k.rows.iter().all(|r| r.policy != training_only));
    k
}

/// A ladder with held-out seeds runs its policies on those seeds alone — layouts none of its
/// demonstrations (the batch's first seeds) had — and the proxy imagines and ranks them there,
/// its world model still learning the training policies' episodes at the batch's seeds.
#[test]
fn a_ladder_with_held_out_seeds_runs_and_ranks_its_policies_there_alone() {
    let ladder = LadderPlan {
        episodes: vec![2],
        checkpoints: vec![5],
        max_steps: 600,
        held_out_seeds: 3,
        ..LadderPlan::default()
    };
    let (mut s, id) = ladder_batch_run(&[0, 1, 2, 3], &ladder);
    let trainer = vec!["trainer".to_owned()];
    let queued = s.lease("t", &trainer, 10, 2, TTL).unwrap();
    let mut world = None;
    for (l, job) in queued.iter().zip(trainer_jobs(&queued)) {
        match job {
            TrainerJob::Diffusion { clips, .. } => {
                assert_eq!(
                    clips,
                    ["clips/0.clip", "clips/2.clip"],
                    "the oracle's first 2"
                );
                let done = diffusion_done_on("policies/m.diffusion", &[], 2);
                assert!(
                    s.complete("t", l.lease_id, l.shard_id, &done, 1.0, 3)
                        .unwrap()
                        .0
                );
            }
            TrainerJob::ProxyWorld { train, .. } => {
                assert!(train.iter().all(|e| e.seed < 4), "{train:?}");
                world = Some(l.clone());
            }
            other => panic!("{other:?}"),
        }
    }
    let ranked = ladder.policy_name("policies/m.diffusion");
    let sim_render: Vec<String> = ["sim", "render"].map(String::from).to_vec();
    let episodes = s.lease("w", &sim_render, 20, 4, TTL).unwrap();
    let mut seeds: Vec<u64> = episodes.iter().map(|l| l.seed).collect();
    seeds.sort_unstable();
    assert_eq!(seeds, [1_000_000, 1_000_001, 1_000_002]);
    assert!(episodes.iter().all(|l| l.policy == ranked));
    for (i, l) in episodes.iter().enumerate() {
        finish_episode(&mut s, l, i == 0, &format!("clips/h{i}.clip"));
    }
    let queued = finish_world_lease_proxy(&mut s, &world.expect("the world model, fitted ahead"));
    let jobs = trainer_jobs(&queued);
    let [TrainerJob::Proxy { train, eval, .. }] = &jobs[..] else {
        panic!("{jobs:?}")
    };
    assert!(train.iter().all(|e| e.seed < 4 && e.policy != ranked));
    let mut eval_seeds: Vec<u64> = eval.iter().map(|e| e.seed).collect();
    eval_seeds.sort_unstable();
    assert_eq!(eval_seeds, seeds);
    let k = finish_proxy_ranking_one(&mut s, &id, &queued[0], eval, &ranked, "oracle");
    let row = k.rows.iter().find(|r| r.policy == ranked).unwrap();
    assert_eq!((row.real.successes, row.real.trials), (1, 3));
    // The report says where the ladder ran, with no caution.
    let seeds = k.ladder_seeds.as_ref().expect("the ladder's seeds");
    assert_eq!((seeds.held_out_seeds, seeds.demonstrations), (3, 2));
    assert!(!seeds.describe().0);
}
