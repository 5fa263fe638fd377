//! The store's tests: submission, leases, completion and the report, end to end on an in-memory
//! (or temporary) store, with time passed in.

use std::collections::BTreeMap;

use assay_model::dynamics::DynamicsConfig;
use assay_model::episode::{EpisodeOutcome, LabelSource, TaskInfo};
use assay_model::proxy::ProxyResult;
use assay_model::quality::{Item, JudgeOutcome};
use assay_model::trainer::{TrainerJob, TrainerOutcome};

use super::schema::SCHEMA;
use super::*;

const TTL: i64 = 1_000;

mod capability;
mod fair;
mod scale;

fn batch(tasks: &[&str], seeds: &[u64], max_attempts: u32) -> NewBatch {
    NewBatch {
        name: "t".into(),
        tasks: tasks
            .iter()
            .map(|id| PlannedTask {
                info: TaskInfo {
                    id: (*id).into(),
                    name: (*id).into(),
                    group: "g".into(),
                    pipeline: "assay".into(),
                    origin: format!("{id}.yaml"),
                    spec_hash: "h".into(),
                },
                spec_json: "{}".into(),
            })
            .collect(),
        policies: vec!["oracle".into()],
        seeds: seeds.to_vec(),
        max_attempts,
        invalid: vec![],
        role: "sim".into(),
        render: false,
        judges: vec![],
        judge_repeats: 0,
        judge_budget_usd: None,
        content_hash: tasks.join(","),
        text_models: Vec::new(),
        text_groups: Vec::new(),
        dynamics: None,
        ranking: None,
        generalization: None,
        share: Default::default(),
    }
}

fn outcome(l: &Lease) -> String {
    serde_json::to_string(&episode(l)).unwrap()
}

fn episode(l: &Lease) -> EpisodeOutcome {
    EpisodeOutcome {
        task_id: "x".into(),
        seed: l.seed,
        policy: l.policy.clone(),
        success: true,
        label_source: LabelSource::Sim,
        predicates: vec![],
        steps: 1,
        sim_time_s: 0.0,
        artifact: String::new(),
        spec_hash: String::new(),
        versions: BTreeMap::new(),
        imagery: None,
        cutoff: None,
        generator_reward: None,
        scenes: None,
    }
}

fn sim() -> Vec<String> {
    vec!["sim".into()]
}

#[test]
fn plans_seed_major_and_completes_once() {
    let mut s = Store::open_in_memory().unwrap();
    let (id, n) = s.submit(&batch(&["a", "b"], &[0, 1], 3), 0).unwrap();
    assert_eq!(n, 4);
    let leases = s.lease("w1", &sim(), 10, 0, TTL).unwrap();
    assert_eq!(leases.len(), 4);
    assert_eq!((leases[0].seed, leases[1].seed, leases[2].seed), (0, 0, 1));
    for l in &leases {
        let (ok, _) = s
            .complete("w1", l.lease_id, l.shard_id, &outcome(l), 0.1, 5)
            .unwrap();
        assert!(ok);
        // A duplicate of the same result is not counted again.
        let (again, _) = s
            .complete("w1", l.lease_id, l.shard_id, &outcome(l), 0.1, 5)
            .unwrap();
        assert!(!again);
    }
    let c = s.counts(&id).unwrap();
    assert_eq!((c.done, c.successes, c.state.as_str()), (4, 4, "completed"));
    assert_eq!(c.finished_ms, Some(5));
}

#[test]
fn expired_lease_requeues_and_late_result_is_rejected() {
    let mut s = Store::open_in_memory().unwrap();
    let (id, _) = s.submit(&batch(&["a"], &[0], 3), 0).unwrap();
    let first = s.lease("w1", &sim(), 1, 0, TTL).unwrap().remove(0);
    // Heartbeats keep it alive past the original deadline.
    assert_eq!(
        s.heartbeat("w1", &[first.lease_id], 900, TTL).unwrap(),
        vec![first.lease_id]
    );
    assert_eq!(s.expire(1_500, None).unwrap().requeued, 0);
    // Silence: it expires and goes back to the queue.
    assert_eq!(s.expire(2_000, None).unwrap().requeued, 1);
    let second = s.lease("w2", &sim(), 1, 2_000, TTL).unwrap().remove(0);
    assert_eq!(second.shard_id, first.shard_id);
    assert_eq!(second.attempt, 2);
    // The first worker's late result does not count; the second's does.
    assert!(
        !s.complete(
            "w1",
            first.lease_id,
            first.shard_id,
            &outcome(&first),
            0.1,
            2_100
        )
        .unwrap()
        .0
    );
    assert!(
        s.complete(
            "w2",
            second.lease_id,
            second.shard_id,
            &outcome(&second),
            0.1,
            2_200
        )
        .unwrap()
        .0
    );
    let c = s.counts(&id).unwrap();
    assert_eq!((c.done, c.total), (1, 1));
    // A heartbeat for a lease the worker no longer holds is refused.
    assert!(
        s.heartbeat("w1", &[first.lease_id], 2_300, TTL)
            .unwrap()
            .is_empty()
    );
}

#[test]
fn failures_retry_a_bounded_number_of_times_then_record_the_error() {
    let mut s = Store::open_in_memory().unwrap();
    let (id, _) = s.submit(&batch(&["a"], &[0], 2), 0).unwrap();
    let l = s.lease("w", &sim(), 1, 0, TTL).unwrap().remove(0);
    assert_eq!(
        s.fail(l.lease_id, l.shard_id, "boom", true, 1)
            .unwrap()
            .requeued,
        1
    );
    let l = s.lease("w", &sim(), 1, 2, TTL).unwrap().remove(0);
    assert_eq!(l.attempt, 2);
    assert_eq!(
        s.fail(l.lease_id, l.shard_id, "boom", true, 3)
            .unwrap()
            .requeued,
        0
    );
    let c = s.counts(&id).unwrap();
    assert_eq!((c.failed, c.state.as_str()), (1, "completed"));
    let r = s.report(&id).unwrap();
    assert_eq!(
        r.results.tasks[0].failures[0].error,
        "boom (after 2 attempts)"
    );
    // Non-retryable errors fail at once.
    let (id2, _) = s.submit(&batch(&["b"], &[0], 5), 0).unwrap();
    let l = s.lease("w", &sim(), 1, 0, TTL).unwrap().remove(0);
    s.fail(l.lease_id, l.shard_id, "bad spec", false, 1)
        .unwrap();
    assert_eq!(s.counts(&id2).unwrap().failed, 1);
}

#[test]
fn returned_leases_do_not_count_as_attempts_and_disconnects_do() {
    let mut s = Store::open_in_memory().unwrap();
    let (_, _) = s.submit(&batch(&["a", "b"], &[0], 1), 0).unwrap();
    let ls = s.lease("w", &sim(), 2, 0, TTL).unwrap();
    s.return_leases("w", &[ls[0].lease_id]).unwrap();
    let again = s.lease("w2", &sim(), 1, 0, TTL).unwrap().remove(0);
    assert_eq!(again.attempt, 1);
    // w disconnects holding ls[1]: with max_attempts 1 the shard fails with the reason.
    let ch = s.expire(10, Some(("w", &[ls[1].lease_id]))).unwrap();
    assert_eq!(ch.requeued, 0);
    let r = s.report(&ls[1].batch_id).unwrap();
    let failure = &r
        .results
        .tasks
        .iter()
        .find(|t| t.id == "b")
        .unwrap()
        .failures[0];
    assert_eq!(failure.attempts, 1);
    assert!(
        failure.error.contains("worker w disconnected"),
        "{}",
        failure.error
    );
}

#[test]
fn survives_reopen_with_leases_intact() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("jobs.db");
    let (id, lease) = {
        let mut s = Store::open(&path).unwrap();
        let (id, _) = s.submit(&batch(&["a", "b"], &[0], 3), 0).unwrap();
        (id, s.lease("w", &sim(), 1, 0, TTL).unwrap().remove(0))
    };
    let mut s = Store::open(&path).unwrap();
    assert_eq!(s.running_batches().unwrap(), vec![id.clone()]);
    assert_eq!(s.refresh_leases(50_000, TTL).unwrap(), 1);
    // The worker reconnects running `lease` and knowing nothing of a second lease that was
    // assigned just before the crash: that one goes back without costing an attempt.
    let lost = s.lease("w", &sim(), 1, 50_000, TTL).unwrap().remove(0);
    let (kept, returned) = s.reconcile("w", &[lease.lease_id, 999]).unwrap();
    assert_eq!(kept, vec![lease.lease_id]);
    assert_eq!(returned.requeued, 1);
    let again = s.lease("w2", &sim(), 1, 50_000, TTL).unwrap().remove(0);
    assert_eq!((again.shard_id, again.attempt), (lost.shard_id, 1));
    assert!(
        s.complete(
            "w",
            lease.lease_id,
            lease.shard_id,
            &outcome(&lease),
            0.1,
            50_001
        )
        .unwrap()
        .0
    );
    // Lease ids keep increasing across reopen.
    assert!(lost.lease_id > lease.lease_id && again.lease_id > lost.lease_id);
}

#[test]
fn cancel_stops_queued_and_leased_shards() {
    let mut s = Store::open_in_memory().unwrap();
    let (id, _) = s.submit(&batch(&["a", "b", "c"], &[0], 3), 0).unwrap();
    let l = s.lease("w", &sim(), 1, 0, TTL).unwrap().remove(0);
    s.cancel(&id, 1).unwrap();
    let c = s.counts(&id).unwrap();
    assert_eq!((c.cancelled, c.state.as_str()), (3, "cancelled"));
    assert!(
        !s.complete("w", l.lease_id, l.shard_id, &outcome(&l), 0.1, 2)
            .unwrap()
            .0
    );
    assert!(s.lease("w", &sim(), 5, 3, TTL).unwrap().is_empty());
}

fn rendered(l: &Lease) -> String {
    rendered_with_clip(l, None)
}

/// A rendered episode's outcome, with a dynamics clip when `clip` is given.
fn rendered_with_clip(l: &Lease, clip: Option<String>) -> String {
    let mut e = episode(l);
    e.imagery = Some(assay_model::episode::EpisodeImagery {
        adapter: "test".into(),
        views: vec![],
        keyframes: vec![],
        contact_sheet: String::new(),
        video: None,
        caption: None,
        clip,
    });
    serde_json::to_string(&e).unwrap()
}

fn judged(l: &Lease, cost: f64) -> String {
    let j = l.judge.as_ref().unwrap();
    serde_json::to_string(&JudgeOutcome {
        judge: j.judge.clone(),
        backend: "openai".into(),
        model: "m".into(),
        task_id: "a".into(),
        seed: l.seed,
        policy: l.policy.clone(),
        repeats: j.repeats,
        items: vec![],
        usage: assay_model::quality::Usage {
            cost_usd: cost,
            ..Default::default()
        },
        transcript: None,
    })
    .unwrap()
}

#[test]
fn rendered_episodes_of_judged_batches_queue_one_judge_shard_per_judge() {
    let mut s = Store::open_in_memory().unwrap();
    let mut b = batch(&["a", "b"], &[0], 3);
    b.judges = vec!["offline".into(), "vlm".into()];
    b.judge_repeats = 3;
    b.judge_budget_usd = Some(1.0);
    let (id, _) = s.submit(&b, 0).unwrap();
    let judge: Vec<String> = ["judge", "judge:offline", "judge:vlm"]
        .map(String::from)
        .to_vec();
    // A judge worker without the vlm judge configured gets the offline judge's shards only.
    let offline_only: Vec<String> = ["judge", "judge:offline"].map(String::from).to_vec();
    let leases = s.lease("w", &sim(), 2, 1, TTL).unwrap();
    // An episode without imagery cannot be judged: nothing is queued for it.
    assert!(
        s.complete(
            "w",
            leases[0].lease_id,
            leases[0].shard_id,
            &outcome(&leases[0]),
            0.1,
            2
        )
        .unwrap()
        .0
    );
    assert!(s.lease("w", &judge, 5, 3, TTL).unwrap().is_empty());
    let c = s.counts(&id).unwrap();
    assert_eq!((c.judge_total, c.state.as_str()), (0, "running"));
    // A rendered one gets a shard per judge, carrying the episode, in the same transaction:
    // the batch is not finished while they wait.
    let (ok, changed) = s
        .complete(
            "w",
            leases[1].lease_id,
            leases[1].shard_id,
            &rendered(&leases[1]),
            0.1,
            4,
        )
        .unwrap();
    assert!(ok);
    assert_eq!(changed.requeued, 2, "judge workers are woken");
    let c = s.counts(&id).unwrap();
    assert_eq!((c.total, c.done, c.judge_total, c.judge_done), (2, 2, 2, 0));
    assert_eq!(c.state, "running");
    let js = s.lease("j0", &offline_only, 5, 5, TTL).unwrap();
    assert_eq!(js.len(), 1);
    assert_eq!(js[0].judge.as_ref().unwrap().judge, "offline");
    s.return_leases("j0", &[js[0].lease_id]).unwrap();
    let js = s.lease("j", &judge, 5, 5, TTL).unwrap();
    assert_eq!(js.len(), 2);
    let names: Vec<&str> = js
        .iter()
        .map(|l| l.judge.as_ref().unwrap().judge.as_str())
        .collect();
    assert_eq!(names, ["offline", "vlm"]);
    for l in &js {
        let j = l.judge.as_ref().unwrap();
        assert_eq!((j.repeats, j.budget_left_usd), (3, Some(1.0)));
        assert_eq!(j.episode_json, rendered(&leases[1]));
        assert_eq!(l.role, "judge");
    }
    // A judge outcome that does not parse is a failed attempt, not a result.
    let (ok, _) = s
        .complete("j", js[0].lease_id, js[0].shard_id, "{\"nope\": 1}", 0.1, 6)
        .unwrap();
    assert!(!ok);
    let again = s.lease("j", &judge, 5, 7, TTL).unwrap();
    assert_eq!(again.len(), 1);
    // What is spent counts against the budget of shards leased later.
    assert!(
        s.complete(
            "j",
            js[1].lease_id,
            js[1].shard_id,
            &judged(&js[1], 0.25),
            0.1,
            8
        )
        .unwrap()
        .0
    );
    assert_eq!(s.counts(&id).unwrap().judge_cost_usd, 0.25);
    s.fail(again[0].lease_id, again[0].shard_id, "flaky", true, 9)
        .unwrap();
    let last = s.lease("j", &judge, 5, 10, TTL).unwrap();
    assert_eq!(last[0].judge.as_ref().unwrap().budget_left_usd, Some(0.75));
    assert!(
        s.complete(
            "j",
            last[0].lease_id,
            last[0].shard_id,
            &judged(&last[0], 0.0),
            0.1,
            11
        )
        .unwrap()
        .0
    );
    let c = s.counts(&id).unwrap();
    assert_eq!((c.judge_done, c.state.as_str()), (2, "completed"));
    // The report has the judges' quality beside the episodes.
    let r = s.report(&id).unwrap();
    assert_eq!(r.results.totals.episodes_completed, 2);
    let q = r.results.quality.unwrap();
    assert_eq!(q.judges.len(), 2);
    assert_eq!(q.judges.iter().map(|j| j.episodes_judged).sum::<u64>(), 2);
}

/// Once a group's episodes are done, one fit per budget on its clips in planning order; a
/// budget at or above the number of clips covers them all, and larger ones are not queued.
#[test]
fn a_finished_group_queues_one_fit_per_budget_its_clips_can_tell_apart() {
    let mut s = Store::open_in_memory().unwrap();
    let mut b = batch(&["a", "b", "c", "d", "e"], &[0], 3);
    b.dynamics = Some(DynamicsPlan {
        budgets: vec![2, 5, 8, 40],
        config: DynamicsConfig::default(),
    });
    let (id, _) = s.submit(&b, 0).unwrap();
    let trainer = vec!["trainer".to_owned()];
    let leases = s.lease("w", &sim(), 5, 1, TTL).unwrap();
    for (i, l) in leases.iter().enumerate() {
        let json = rendered_with_clip(l, Some(format!("clips/{i}.clip")));
        assert!(
            s.complete("w", l.lease_id, l.shard_id, &json, 0.1, 2)
                .unwrap()
                .0
        );
        // Nothing is trained while the group still has episodes to run.
        let queued = s.lease("t", &trainer, 10, 2, TTL).unwrap();
        assert_eq!(queued.is_empty(), i + 1 < leases.len(), "after episode {i}");
        if !queued.is_empty() {
            let jobs: Vec<TrainerJob> = queued
                .iter()
                .map(|l| serde_json::from_str(l.trainer_job.as_deref().unwrap()).unwrap())
                .collect();
            let clips: Vec<String> = (0..5).map(|i| format!("clips/{i}.clip")).collect();
            let budgets: Vec<u32> = jobs
                .iter()
                .map(|j| match j {
                    TrainerJob::Dynamics {
                        group,
                        budget,
                        clips: c,
                        ..
                    } => {
                        assert_eq!((group.as_str(), c), ("g", &clips));
                        *budget
                    }
                    other => panic!("{other:?}"),
                })
                .collect();
            assert_eq!(budgets, [2, 5]);
        }
    }
    let c = s.counts(&id).unwrap();
    assert_eq!((c.trainer_total, c.state.as_str()), (2, "running"));
}

#[test]
fn a_ranking_batch_queues_one_proxy_per_group_that_never_sees_the_ranked_outcomes() {
    use assay_model::episode::Keyframe;
    use assay_model::proxy::{ProxyConfig, ProxyPrediction};
    use assay_model::quality::ItemOutcome;
    let mut s = Store::open_in_memory().unwrap();
    let tasks = ["a", "b"];
    let mut b = batch(&tasks, &[0, 1], 3);
    let policies = ["oracle", "oracle:noise=0.03", "oracle:noise=0.01"];
    b.policies = policies.iter().map(|p| p.to_string()).collect();
    // The offline judge judges the real episodes only; a VLM judges the imagined ones too.
    b.judges = vec!["offline".into(), "vlm".into()];
    b.ranking = Some(RankingPlan {
        train_policies: vec!["oracle:noise=0.01".into()],
        config: ProxyConfig::default(),
        ladder: None,
        groups: Vec::new(),
    });
    let (id, n) = s.submit(&b, 0).unwrap();
    assert_eq!(n, 12);
    let trainer = vec!["trainer".to_owned()];
    let leases = s.lease("w", &sim(), 12, 1, TTL).unwrap();
    // Every episode of a ranking batch renders a clip of the proxy's frame size.
    assert!(leases.iter().all(|l| l.clip_size == 64));
    let mut truth = std::collections::HashMap::new();
    for (i, l) in leases.iter().enumerate() {
        // Seed-major, then policy, then task.
        assert_eq!(l.policy, policies[(i / 2) % 3]);
        let mut e = episode(l);
        e.task_id = tasks[i % 2].into();
        e.success = i % 3 != 0;
        e.imagery = Some(assay_model::episode::EpisodeImagery {
            adapter: "test".into(),
            views: vec![],
            keyframes: vec![],
            contact_sheet: String::new(),
            video: None,
            caption: None,
            clip: Some(format!("clips/{i}.clip")),
        });
        truth.insert((e.task_id.clone(), e.policy.clone(), e.seed), e.success);
        let json = serde_json::to_string(&e).unwrap();
        assert!(
            s.complete("w", l.lease_id, l.shard_id, &json, 0.1, 2)
                .unwrap()
                .0
        );
    }
    let judge: Vec<String> = ["judge", "judge:offline", "judge:vlm"]
        .map(String::from)
        .to_vec();
    let real_judging = s.lease("j", &judge, 100, 2, TTL).unwrap();
    assert_eq!(real_judging.len(), 24);
    for l in &real_judging {
        assert!(
            s.complete("j", l.lease_id, l.shard_id, &judged(l, 0.0), 0.1, 2)
                .unwrap()
                .0
        );
    }
    let queued = s.lease("t", &trainer, 10, 3, TTL).unwrap();
    assert_eq!(queued.len(), 1);
    let input = queued[0].trainer_job.clone().unwrap();
    let TrainerJob::Proxy {
        group, train, eval, ..
    } = serde_json::from_str(&input).unwrap()
    else {
        panic!("{input}")
    };
    assert_eq!(group, "g");
    assert_eq!(train.len(), 4);
    assert!(
        train
            .iter()
            .all(|e| e.policy == "oracle:noise=0.01" && e.success.is_some())
    );
    assert_eq!(eval.len(), 8);
    // The ranked episodes' outcomes never reach the trainer.
    assert!(
        eval.iter()
            .all(|e| e.success.is_none() && e.policy != "oracle:noise=0.01")
    );
    assert_eq!(input.matches("\"success\"").count(), 4);
    // The proxy predicts the opposite of the truth for one ranked episode.
    let predictions = eval
        .iter()
        .map(|e| {
            let real = truth[&(e.task_id.clone(), e.policy.clone(), e.seed)];
            let wrong = e.task_id == "a" && e.seed == 0 && e.policy == "oracle";
            let success = real != wrong;
            ProxyPrediction {
                p_success: if success { 0.9 } else { 0.1 },
                p_success_real_frame: if real { 0.8 } else { 0.2 },
                last_frame_mse: 0.001,
                imagined_keyframes: (0..8)
                    .map(|k| Keyframe {
                        step: k,
                        camera: "imagined".into(),
                        artifact: format!("imagery/{}-{}-{k}.png", e.task_id, e.seed),
                        goals_met: 0,
                    })
                    .collect(),
                ..prediction(e, success)
            }
        })
        .collect();
    let json = proxy_done(predictions);
    let l = &queued[0];
    assert!(
        s.complete("t", l.lease_id, l.shard_id, &json, 1.0, 4)
            .unwrap()
            .0
    );
    // The VLM is asked about every imagined rollout: the real episode with the imagined
    // keyframes for imagery and no scene views. The batch waits for it.
    assert_eq!(s.counts(&id).unwrap().state, "running");
    let imagined = s.lease("j", &judge, 100, 5, TTL).unwrap();
    assert_eq!(imagined.len(), 8);
    for (k, l) in imagined.iter().enumerate() {
        let j = l.judge.as_ref().unwrap();
        assert_eq!(j.judge, "vlm");
        let e: EpisodeOutcome = serde_json::from_str(&j.episode_json).unwrap();
        let img = e.imagery.unwrap();
        assert!(img.views.is_empty());
        assert_eq!(img.keyframes.len(), 8);
        assert!(
            img.keyframes[7]
                .artifact
                .ends_with(&format!("{}-{}-7.png", e.task_id, e.seed))
        );
        if k == 0 {
            s.fail(l.lease_id, l.shard_id, "HTTP 400", false, 6)
                .unwrap();
            continue;
        }
        // The VLM says what really happened.
        let real = truth[&(e.task_id.clone(), e.policy.clone(), e.seed)];
        let mut o: JudgeOutcome = serde_json::from_str(&judged(l, 0.0)).unwrap();
        o.task_id = e.task_id.clone();
        o.items = vec![ItemOutcome {
            item: Item::Completion,
            prompt: "completion/v1".into(),
            scores: vec![if real { 9.0 } else { 1.0 }],
            errors: vec![],
            unjudged: 0,
        }];
        let o = serde_json::to_string(&o).unwrap();
        assert!(
            s.complete("j", l.lease_id, l.shard_id, &o, 0.1, 6)
                .unwrap()
                .0
        );
    }
    assert_eq!(s.counts(&id).unwrap().state, "completed");
    let k = s.report(&id).unwrap().results.ranking.unwrap();
    assert_eq!(k.ranked_policies, ["oracle", "oracle:noise=0.03"]);
    assert_eq!(k.rows.len(), 4);
    assert!(
        k.rows
            .iter()
            .all(|r| r.real.trials == 2 && r.proxy.as_ref().unwrap().trials == 2)
    );
    let agree = k.proxy_agreement.unwrap();
    assert_eq!((agree.successes, agree.trials), (7, 8));
    let judge = k.judge_agreement_real_frames.unwrap();
    assert_eq!((judge.successes, judge.trials), (8, 8));
    // Verdicts on imagined rollouts are a proxy of their own, not quality.
    assert_eq!(k.judging_errors.len(), 1);
    assert!(k.judging_errors[0].4.contains("HTTP 400"));
    let judged: u64 = k
        .rows
        .iter()
        .flat_map(|r| &r.judged_proxy)
        .map(|j| j.success.trials)
        .sum();
    assert_eq!(judged, 7);
    let ranking = k.ranking.expect("two policies ranked");
    let proxies: Vec<&str> = ranking
        .comparisons
        .iter()
        .map(|c| c.proxy.as_str())
        .collect();
    assert_eq!(proxies, ["world-model", "world-model+vlm"]);
    assert_eq!(ranking.comparisons[0].policies.len(), 2);
    assert_eq!(ranking.comparisons[1].mmrv.value, Some(0.0));
    // The VLM's quality covers the batch's 12 real episodes, not its imagined rollouts.
    let q = s.report(&id).unwrap().results.quality.unwrap();
    let vlm = q.judges.iter().find(|j| j.judge == "vlm").unwrap();
    assert_eq!((vlm.episodes_judged, vlm.episodes_failed), (12, 0));
}

/// A world model's fit of group `g` on 4 episodes, evaluated on `eval_episodes`.
fn dynamics_fit(eval_episodes: u32) -> assay_model::dynamics::DynamicsFit {
    serde_json::from_value(serde_json::json!({
        "group": "g", "budget": 4, "train_episodes": 4, "eval_episodes": eval_episodes,
        "eval_image_mse": 0.001, "eval_proprio_mse": 0.0, "per_episode": [], "episodes": [],
        "final_train_loss": 1.0, "steps": 10, "epochs": 1.0, "device": "cpu", "config": {}
    }))
    .unwrap()
}

/// A finished proxy of group `g` with these predictions.
fn proxy_done(predictions: Vec<assay_model::proxy::ProxyPrediction>) -> String {
    serde_json::to_string(&TrainerOutcome::Proxy {
        result: Box::new(ProxyResult {
            group: "g".into(),
            world_model_name: String::new(),
            action_test: None,
            world_model: dynamics_fit(8),
            video_model: None,
            judge_examples: 8,
            judge_positives: 5,
            judge_train_accuracy: 1.0,
            object_judge_train_accuracy: None,
            judge_latest_not_done: None,
            ranked_last_frame: None,
            calibration: None,
            cross_family: Vec::new(),
            cross_fit: Vec::new(),
            predictions,
            seconds: 1.0,
            imagined_frames: Vec::new(),
            imagined_frame_size: (0, 0),
        }),
    })
    .unwrap()
}

/// A fitted world model of group `g` (a proxy's, fitted ahead of it) at `checkpoint`.
fn proxy_world_done(checkpoint: &str) -> String {
    serde_json::to_string(&TrainerOutcome::ProxyWorld {
        group: "g".into(),
        checkpoint: checkpoint.into(),
        fit: Box::new(dynamics_fit(1)),
    })
    .unwrap()
}

/// A trained diffusion policy of group `g`, with the policies kept at its checkpoints.
fn diffusion_done(model: &str, checkpoints: &[(u64, &str)]) -> String {
    diffusion_done_on(model, checkpoints, 2)
}

/// [`diffusion_done`] of a run that trained on `clips` clips.
fn diffusion_done_on(model: &str, checkpoints: &[(u64, &str)], clips: u32) -> String {
    let config = assay_model::diffusion::DiffusionConfig::default();
    serde_json::to_string(&TrainerOutcome::Diffusion {
        group: "g".into(),
        model: model.into(),
        fit: Box::new(assay_model::diffusion::DiffusionFit {
            steps: config.steps,
            final_loss: 0.1,
            mean_last_100_loss: 0.1,
            train_seconds: 1.0,
            parameters: 1,
            clips,
            samples: 10,
            device: "cpu".into(),
            libtorch: String::new(),
            config,
        }),
        checkpoints: checkpoints
            .iter()
            .map(|(s, k)| (*s, (*k).to_owned()))
            .collect(),
    })
    .unwrap()
}

/// Completes an episode lease of a task whose spec JSON names its `id`, rendered with a clip.
fn finish_episode(s: &mut Store, l: &Lease, success: bool, clip: &str) {
    let spec: serde_json::Value = serde_json::from_str(&l.task_spec_json).unwrap();
    let mut e = episode(l);
    e.task_id = spec["id"].as_str().unwrap().into();
    e.success = success;
    e.imagery = Some(assay_model::episode::EpisodeImagery {
        adapter: "test".into(),
        views: vec![],
        keyframes: vec![],
        contact_sheet: String::new(),
        video: None,
        caption: None,
        clip: Some(clip.into()),
    });
    let json = serde_json::to_string(&e).unwrap();
    assert!(
        s.complete("w", l.lease_id, l.shard_id, &json, 0.1, 2)
            .unwrap()
            .0
    );
}

fn trainer_jobs(leases: &[Lease]) -> Vec<TrainerJob> {
    leases
        .iter()
        .map(|l| serde_json::from_str(l.trainer_job.as_deref().unwrap()).unwrap())
        .collect()
}

#[test]
fn a_store_from_before_judges_gains_their_columns() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("old.db");
    {
        let conn = Connection::open(&path).unwrap();
        conn.execute_batch(SCHEMA).unwrap();
        conn.execute_batch(
            "INSERT INTO batches (id, seq, name, state, policies_json, seeds_json, max_attempts, invalid_json, submitted_ms)
             VALUES ('b1', 1, 'old', 'completed', '[\"oracle\"]', '[0]', 3, '[]', 0)",
        )
        .unwrap();
    }
    let s = Store::open(&path).unwrap();
    let r = s.report("b1").unwrap();
    assert!(r.results.quality.is_none());
    let mut s = s;
    let (id, _) = s.submit(&batch(&["a"], &[0], 3), 1).unwrap();
    assert_eq!(s.counts(&id).unwrap().total, 1);
}

/// A proxy's verdict on `e`, every diagnostic left empty.
fn prediction(
    e: &assay_model::proxy::ProxyEpisode,
    success: bool,
) -> assay_model::proxy::ProxyPrediction {
    assay_model::proxy::ProxyPrediction {
        task_id: e.task_id.clone(),
        policy: e.policy.clone(),
        seed: e.seed,
        p_success: 0.5,
        success,
        p_success_real_frame: 0.5,
        last_frame_mse: 0.0,
        imagined_frames: 0,
        done_by_judge: false,
        p_calibrated: None,
        leak: None,
        cross_family: None,
        cross_fit: None,
        object_judge: None,
        imagined_keyframes: Vec::new(),
    }
}

mod groups;
mod kinds;
mod ladder;
mod writes;
