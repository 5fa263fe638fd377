//! Builders of the records the report crate's tests aggregate (shared by `report`, `quality`,
//! `generalization`, `tables` and `html`'s tests).

use assay_model::episode::{JudgeRecord, TaskInfo};
use assay_model::quality::{Item, ItemOutcome, JudgeOutcome, Usage};

/// A trained diffusion policy's fit, as the generalization section reads it (10 steps, 4 clips).
pub(crate) fn diffusion_fit() -> assay_model::diffusion::DiffusionFit {
    serde_json::from_value(serde_json::json!({
        "steps": 10, "final_loss": 0.1, "mean_last_100_loss": 0.1,
        "parameters": 5, "clips": 4, "samples": 40, "device": "cpu", "config": {}
    }))
    .unwrap()
}

/// A task of pipeline `assay` whose name is its id.
pub(crate) fn info(id: &str, group: &str) -> TaskInfo {
    TaskInfo {
        id: id.into(),
        name: id.into(),
        group: group.into(),
        pipeline: "assay".into(),
        origin: String::new(),
        spec_hash: "h".into(),
    }
}

/// Scores of one item, asked with its version-1 prompt.
pub(crate) fn item(item: Item, scores: &[f64]) -> ItemOutcome {
    ItemOutcome {
        item,
        prompt: format!("{}/v1", item.name()),
        scores: scores.to_vec(),
        errors: Vec::new(),
        unjudged: 0,
    }
}

/// A finished judge shard of the `oracle` episode (task, seed): scene-alignment scores `sa` and
/// completion scores `c`, by the offline judge's backend and model, spending nothing.
pub(crate) fn judged(judge: &str, task: &str, seed: u64, sa: &[f64], c: &[f64]) -> JudgeRecord {
    JudgeRecord {
        task_id: task.into(),
        seed,
        policy: "oracle".into(),
        judge: judge.into(),
        attempts: 1,
        outcome: Some(JudgeOutcome {
            judge: judge.into(),
            backend: "offline".into(),
            model: "caption".into(),
            task_id: task.into(),
            seed,
            policy: "oracle".into(),
            repeats: 2,
            items: vec![item(Item::SceneAlignment, sa), item(Item::Completion, c)],
            usage: Usage::default(),
            transcript: None,
        }),
        error: None,
        cancelled: false,
    }
}

/// Two ranked diffusion policies of a ladder, shortened in the tables as `diffusion 3fa9c2d1`
/// and `diffusion 77be01aa`.
pub(crate) const LADDER_BEST: &str =
    "diffusion:model=policies/3fa9c2d1e8b74a60.diffusion,max_steps=6000";
pub(crate) const LADDER_WORST: &str =
    "diffusion:model=policies/77be01aa0c3f9d12.diffusion,max_steps=6000";

/// A ranking of three policies (the ladder's two and `scripted`) over two groups — g1: tasks a
/// and b, the RSSM, an action test; g2: task c, a served world model — two seeds per task, with
/// the leak ablation and one judge (`vlm`, k = 3) on task a's imagined rollouts.
///
/// Real success: best 6/6, scripted 3/6 (seed 0), worst 1/6 (a, seed 0). The frame judge's
/// proxy: best 5/6 (not c, seed 1), scripted 2/6 (a and b, seed 0), worst 0/6; the leak
/// ablation equals the real outcome. `vlm`'s scores on task a: best [8, 9, 10] and [6, 6, 6]
/// (variances 1 and 0), scripted [4, 6, 8] and [2, 2, 5] (4 and 3, both split by the threshold
/// 5), worst [1, 1, 1] and [0, 3] of 3 asked (0 and 4.5); on b / worst / seed 0 it failed.
pub(crate) fn ranking_fixture() -> crate::ranking::RankingResults {
    use crate::ranking::{RealEpisode, ranking_results};
    use assay_model::dynamics::{DynamicsConfig, DynamicsFit};
    use assay_model::proxy::{
        ActionTest, ImaginedJudgement, LeakVerdict, ProxyConfig, ProxyPrediction, ProxyResult,
        RankingPlan,
    };

    let ranked: Vec<String> = vec![LADDER_BEST.into(), "scripted".into(), LADDER_WORST.into()];
    let task_groups: Vec<(String, String)> = [("a", "g1"), ("b", "g1"), ("c", "g2")]
        .map(|(t, g)| (t.to_owned(), g.to_owned()))
        .to_vec();
    let real = |task: &str, policy: &str, seed: u64| match policy {
        LADDER_BEST => true,
        "scripted" => seed == 0,
        _ => task == "a" && seed == 0,
    };
    let proxy = |task: &str, policy: &str, seed: u64| match policy {
        LADDER_BEST => !(task == "c" && seed == 1),
        "scripted" => seed == 0 && task != "c",
        _ => false,
    };
    let mut episodes = Vec::new();
    let mut predictions: Vec<(String, ProxyPrediction)> = Vec::new();
    for (task, group) in &task_groups {
        for policy in &ranked {
            for seed in [0, 1] {
                let success = real(task, policy, seed);
                episodes.push(RealEpisode {
                    task_id: task.clone(),
                    policy: policy.clone(),
                    seed,
                    success,
                    judged_completion: None,
                    completion_by_judge: Vec::new(),
                });
                let ok = proxy(task, policy, seed);
                predictions.push((
                    group.clone(),
                    ProxyPrediction {
                        task_id: task.clone(),
                        policy: policy.clone(),
                        seed,
                        p_success: if ok { 0.8 } else { 0.2 },
                        success: ok,
                        p_success_real_frame: if success { 0.9 } else { 0.1 },
                        last_frame_mse: 0.004,
                        imagined_frames: if ok { 20 } else { 40 },
                        done_by_judge: ok,
                        p_calibrated: None,
                        leak: Some(LeakVerdict {
                            p_success: if success { 0.7 } else { 0.3 },
                            success,
                        }),
                        cross_family: None,
                        cross_fit: None,
                        object_judge: None,
                        imagined_keyframes: Vec::new(),
                    },
                ));
            }
        }
    }
    let fit = |group: &str| DynamicsFit {
        group: group.into(),
        budget: 8,
        train_episodes: 8,
        eval_episodes: 4,
        eval_image_mse: 0.0012,
        eval_proprio_mse: 0.0,
        per_episode: Vec::new(),
        episodes: Vec::new(),
        final_train_loss: 0.1,
        steps: 500,
        epochs: 10.0,
        resumed_from_step: None,
        steps_per_s: 100.0,
        device: "cpu".into(),
        libtorch: String::new(),
        config: DynamicsConfig::default(),
    };
    let group = |name: &str, model: &str, action_test: Option<ActionTest>| ProxyResult {
        group: name.into(),
        world_model_name: model.into(),
        action_test,
        world_model: fit(name),
        video_model: None,
        judge_examples: 40,
        judge_positives: 12,
        judge_train_accuracy: 0.95,
        object_judge_train_accuracy: None,
        judge_latest_not_done: Some(40),
        ranked_last_frame: Some(60),
        calibration: None,
        cross_family: Vec::new(),
        cross_fit: Vec::new(),
        predictions: predictions
            .iter()
            .filter(|(g, _)| g == name)
            .map(|(_, p)| p.clone())
            .collect(),
        seconds: 0.0,
        imagined_frames: Vec::new(),
        imagined_frame_size: (0, 0),
    };
    let groups = vec![
        group("g2", "cosmos (http://wm:50051)", None),
        group(
            "g1",
            "assay RSSM",
            Some(ActionTest {
                episodes: 4,
                windows: 6,
                horizon: 16,
                true_actions_mse: 0.002,
                shuffled_actions_mse: 0.005,
                zero_actions_mse: 0.008,
                psnr: 27.0,
                ssim: 0.9,
            }),
        ),
    ];
    let verdict = |task: &str, policy: &str, seed: u64, scores: &[f64]| ImaginedJudgement {
        task_id: task.into(),
        policy: policy.into(),
        seed,
        judge: "vlm".into(),
        completion: Ok(scores.iter().sum::<f64>() / scores.len() as f64),
        scores: scores.to_vec(),
        repeats: 3,
    };
    let mut imagined = vec![
        verdict("a", LADDER_BEST, 0, &[8.0, 9.0, 10.0]),
        verdict("a", LADDER_BEST, 1, &[6.0, 6.0, 6.0]),
        verdict("a", "scripted", 0, &[4.0, 6.0, 8.0]),
        verdict("a", "scripted", 1, &[2.0, 2.0, 5.0]),
        verdict("a", LADDER_WORST, 0, &[1.0, 1.0, 1.0]),
        verdict("a", LADDER_WORST, 1, &[0.0, 3.0]),
    ];
    imagined.push(ImaginedJudgement {
        completion: Err("HTTP 500".into()),
        scores: Vec::new(),
        repeats: 0,
        ..verdict("b", LADDER_WORST, 0, &[0.0])
    });
    let plan = RankingPlan {
        train_policies: vec!["oracle".into()],
        config: ProxyConfig {
            leak_ablation: true,
            ..ProxyConfig::default()
        },
        ladder: None,
        groups: Vec::new(),
    };
    ranking_results(
        &plan,
        &ranked,
        &task_groups,
        &episodes,
        groups,
        &imagined,
        Vec::new(),
    )
}

/// A report of tasks a, b (group g1) and c (g2) with no episodes of its own and `ranking` as its
/// ranking section.
pub(crate) fn report_with_ranking(
    ranking: crate::ranking::RankingResults,
) -> crate::report::Report {
    let tasks = [info("a", "g1"), info("b", "g1"), info("c", "g2")];
    let mut results =
        crate::report::build_results("ranking", &["oracle".into()], &[0, 1], &tasks, &[], &[]);
    results.ranking = Some(ranking);
    crate::report::Report {
        report_version: crate::report::REPORT_VERSION,
        results,
        run: crate::report::RunInfo::default(),
        provenance: Default::default(),
        imports: Vec::new(),
    }
}
