//! The policy-ranking section of a report (the video-world-model paper, §III): per (task,
//! ranked policy) the real success from the simulator, the world-model proxy's and the judges'
//! verdicts on imagined rollouts, and the ranking statistics of the proxies against the real rates
//! ([`assay_stats::ranking`]). The proxy's plans and the trainer's results are
//! [`assay_model::proxy`]'s.
//!
//! Owns: the aggregation. Never trains, imagines or judges anything.

use serde::{Deserialize, Serialize};

use assay_model::proxy::{
    ImaginedJudgement, JudgedProxy, PROXY_SOURCE, ProxyPrediction, ProxyResult, REAL_SOURCE,
    RankingPlan, judged_source,
};
use assay_stats::ranking::{Cell, Ranking, RankingConfig, rank};
use assay_stats::stats::Proportion;

/// One ranked episode as the report builder reads it from the store.
#[derive(Debug, Clone, PartialEq)]
pub struct RealEpisode {
    pub task_id: String,
    pub policy: String,
    pub seed: u64,
    pub success: bool,
    /// Mean completion score (0–10) of the batch's judges on this episode, when judged.
    pub judged_completion: Option<f64>,
}

/// Real, proxy and judged success of one (task, ranked policy).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct RankingRow {
    pub task_id: String,
    pub group: String,
    pub policy: String,
    /// Ground truth: the simulator's predicates.
    pub real: Proportion,
    /// The world-model proxy's verdicts (absent until the group's proxy job is done).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub proxy: Option<Proportion>,
    /// Mean of the frame judge's probabilities on the imagined last frames.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub proxy_mean_p: Option<f64>,
    /// Mean completion (0–10) the batch's judges gave the real rollouts, when they were judged.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub judged_completion: Option<f64>,
    /// The judge role's verdicts on the imagined rollouts, one per judge (VLM judges only).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub judged_proxy: Vec<JudgedProxy>,
}

/// The policy-ranking section of a report.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct RankingResults {
    pub train_policies: Vec<String>,
    pub ranked_policies: Vec<String>,
    pub rows: Vec<RankingRow>,
    /// Per group: the world model, the frame judge and every prediction.
    pub groups: Vec<ProxyResult>,
    /// Pearson, MMRV, Spearman and Kendall of the proxy against the real success rates, over the
    /// tasks whose proxy is done.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ranking: Option<Ranking>,
    /// Why there is no ranking yet (or at all).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ranking_missing: Option<String>,
    /// Of the ranked episodes the proxy judged: how often its verdict matches the real outcome,
    /// and how often the frame judge is right on the *real* last frames (its own error, without
    /// the world model's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub proxy_agreement: Option<Proportion>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub judge_agreement_real_frames: Option<Proportion>,
    /// Proxy jobs that failed: (group, error).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub errors: Vec<(String, String)>,
    /// Imagined rollouts the judge role could not judge: (judge, task, policy, seed, error).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub judging_errors: Vec<(String, String, String, u64, String)>,
}

/// The correlation plot written beside `report.md` (predicted against real success).
pub const RANKING_FIGURE: &str = "ranking.svg";

/// The file of the correlation plot of `proxy`: [`RANKING_FIGURE`] for the frame judge's, one
/// per judge for the judge role's verdicts on imagined rollouts.
pub fn ranking_figure(proxy: &str) -> String {
    match proxy.strip_prefix(&format!("{PROXY_SOURCE}+")) {
        Some(judge) => {
            let safe: String = judge
                .chars()
                .map(|c| {
                    if c.is_ascii_alphanumeric() || c == '-' {
                        c
                    } else {
                        '_'
                    }
                })
                .collect();
            format!("ranking-{safe}.svg")
        }
        None => RANKING_FIGURE.to_owned(),
    }
}

/// Bootstrap resamples of the report's ranking statistics.
pub const RANKING_RESAMPLES: usize = 2000;

/// Builds the ranking section: `episodes` are the finished episodes of the ranked policies,
/// `groups` the finished proxy jobs, `imagined` the judge role's verdicts on their imagined
/// rollouts, `task_groups` (task id, group) in report order.
pub fn ranking_results(
    plan: &RankingPlan,
    ranked_policies: &[String],
    task_groups: &[(String, String)],
    episodes: &[RealEpisode],
    mut groups: Vec<ProxyResult>,
    imagined: &[ImaginedJudgement],
    errors: Vec<(String, String)>,
) -> RankingResults {
    let mut judges: Vec<&str> = imagined.iter().map(|j| j.judge.as_str()).collect();
    judges.sort_unstable();
    judges.dedup();
    let group_order = |g: &str| task_groups.iter().position(|(_, x)| x == g);
    groups.sort_by_key(|r| group_order(&r.group));
    let predictions: Vec<&ProxyPrediction> =
        groups.iter().flat_map(|g| g.predictions.iter()).collect();
    let mut rows = Vec::new();
    let mut cells = Vec::new();
    let mut agree = (0u64, 0u64);
    let mut judge_real = (0u64, 0u64);
    for (task, group) in task_groups {
        for policy in ranked_policies {
            let eps: Vec<&RealEpisode> = episodes
                .iter()
                .filter(|e| &e.task_id == task && &e.policy == policy)
                .collect();
            if eps.is_empty() {
                continue;
            }
            let real_ok = eps.iter().filter(|e| e.success).count() as u64;
            let real = Proportion::new(real_ok, eps.len() as u64);
            let preds: Vec<&ProxyPrediction> = predictions
                .iter()
                .copied()
                .filter(|p| &p.task_id == task && &p.policy == policy)
                .collect();
            for p in &preds {
                if let Some(e) = eps.iter().find(|e| e.seed == p.seed) {
                    agree.1 += 1;
                    agree.0 += u64::from(p.success == e.success);
                    judge_real.1 += 1;
                    judge_real.0 +=
                        u64::from((p.p_success_real_frame >= plan.config.threshold) == e.success);
                }
            }
            let proxy = (!preds.is_empty()).then(|| {
                Proportion::new(
                    preds.iter().filter(|p| p.success).count() as u64,
                    preds.len() as u64,
                )
            });
            let judged: Vec<f64> = eps.iter().filter_map(|e| e.judged_completion).collect();
            let mut judged_proxy = Vec::new();
            for judge in &judges {
                let scores: Vec<f64> = imagined
                    .iter()
                    .filter(|j| j.judge == *judge && &j.task_id == task && &j.policy == policy)
                    .filter_map(|j| j.completion.as_ref().ok().copied())
                    .collect();
                if scores.is_empty() {
                    continue;
                }
                let ok = scores
                    .iter()
                    .filter(|c| **c >= plan.config.completion_threshold)
                    .count() as u64;
                let success = Proportion::new(ok, scores.len() as u64);
                cells.push(Cell {
                    task: task.clone(),
                    policy: policy.clone(),
                    source: judged_source(judge),
                    trials: Some(success.trials),
                    successes: Some(success.successes),
                    rate: success.rate.unwrap_or(0.0),
                });
                judged_proxy.push(JudgedProxy {
                    judge: (*judge).to_owned(),
                    success,
                    mean_completion: Some(scores.iter().sum::<f64>() / scores.len() as f64),
                });
            }
            cells.push(Cell {
                task: task.clone(),
                policy: policy.clone(),
                source: REAL_SOURCE.into(),
                trials: Some(real.trials),
                successes: Some(real.successes),
                rate: real.rate.unwrap_or(0.0),
            });
            if let Some(p) = &proxy {
                cells.push(Cell {
                    task: task.clone(),
                    policy: policy.clone(),
                    source: PROXY_SOURCE.into(),
                    trials: Some(p.trials),
                    successes: Some(p.successes),
                    rate: p.rate.unwrap_or(0.0),
                });
            }
            rows.push(RankingRow {
                task_id: task.clone(),
                group: group.clone(),
                policy: policy.clone(),
                real,
                proxy,
                proxy_mean_p: (!preds.is_empty())
                    .then(|| preds.iter().map(|p| p.p_success).sum::<f64>() / preds.len() as f64),
                judged_completion: (!judged.is_empty())
                    .then(|| judged.iter().sum::<f64>() / judged.len() as f64),
                judged_proxy,
            });
        }
    }
    // The frame judge's proxy first, then each judge's, as far as they have verdicts.
    let proxies: Vec<String> = std::iter::once(PROXY_SOURCE.to_owned())
        .chain(judges.iter().map(|j| judged_source(j)))
        .filter(|p| cells.iter().any(|c| &c.source == p))
        .collect();
    let (ranking, ranking_missing) = if proxies.is_empty() {
        (None, Some("no proxy job has finished".to_owned()))
    } else {
        let cfg = RankingConfig {
            real: REAL_SOURCE.into(),
            proxies,
            resamples: RANKING_RESAMPLES,
            seed: 0,
        };
        match rank(&cells, &cfg) {
            Ok(r) => (Some(r), None),
            Err(e) => (None, Some(e)),
        }
    };
    RankingResults {
        train_policies: plan.train_policies.clone(),
        ranked_policies: ranked_policies.to_vec(),
        rows,
        groups,
        ranking,
        ranking_missing,
        proxy_agreement: (agree.1 > 0).then(|| Proportion::new(agree.0, agree.1)),
        judge_agreement_real_frames: (judge_real.1 > 0)
            .then(|| Proportion::new(judge_real.0, judge_real.1)),
        errors,
        judging_errors: imagined
            .iter()
            .filter_map(|j| {
                j.completion.as_ref().err().map(|e| {
                    (
                        j.judge.clone(),
                        j.task_id.clone(),
                        j.policy.clone(),
                        j.seed,
                        e.clone(),
                    )
                })
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use assay_model::proxy::ProxyConfig;

    fn real(task: &str, policy: &str, seed: u64, success: bool) -> RealEpisode {
        RealEpisode {
            task_id: task.into(),
            policy: policy.into(),
            seed,
            success,
            judged_completion: None,
        }
    }

    fn verdict(
        judge: &str,
        task: &str,
        policy: &str,
        seed: u64,
        completion: Result<f64, &str>,
    ) -> ImaginedJudgement {
        ImaginedJudgement {
            task_id: task.into(),
            policy: policy.into(),
            seed,
            judge: judge.into(),
            completion: completion.map_err(str::to_owned),
        }
    }

    #[test]
    fn each_judge_of_imagined_rollouts_is_a_proxy_of_its_own() {
        let plan = RankingPlan {
            train_policies: vec!["teacher".into()],
            config: ProxyConfig::default(),
        };
        let ranked: Vec<String> = ["good", "fair", "poor"].map(String::from).to_vec();
        let task_groups = vec![("t1".into(), "g".into()), ("t2".into(), "g".into())];
        let mut episodes = Vec::new();
        let mut imagined = Vec::new();
        // Real success: good 4/4, fair 2/4, poor 0/4. The VLM's completions on the imagined
        // rollouts follow it (threshold 5: 4/4, 2/4, 0/3 and one error); "coarse" judges only
        // two policies and gets them the wrong way round.
        let vlm = [
            ("good", [9.0, 8.0, 7.0, 6.0]),
            ("fair", [6.0, 2.0, 5.0, 1.0]),
            ("poor", [1.0, 0.0, 4.9, f64::NAN]),
        ];
        for (policy, scores) in vlm {
            for (k, score) in scores.into_iter().enumerate() {
                let (task, seed) = (if k < 2 { "t1" } else { "t2" }, k as u64 % 2);
                let ok = match policy {
                    "good" => true,
                    "fair" => seed == 0,
                    _ => false,
                };
                episodes.push(real(task, policy, seed, ok));
                imagined.push(verdict(
                    "vlm",
                    task,
                    policy,
                    seed,
                    if score.is_nan() {
                        Err("HTTP 500")
                    } else {
                        Ok(score)
                    },
                ));
            }
        }
        imagined.push(verdict("coarse", "t1", "good", 0, Ok(2.0)));
        imagined.push(verdict("coarse", "t1", "poor", 0, Ok(8.0)));
        let r = ranking_results(
            &plan,
            &ranked,
            &task_groups,
            &episodes,
            Vec::new(),
            &imagined,
            Vec::new(),
        );

        let ranking = r.ranking.as_ref().unwrap_or_else(|| panic!("{r:?}"));
        let proxies: Vec<&str> = ranking
            .comparisons
            .iter()
            .map(|c| c.proxy.as_str())
            .collect();
        // No frame-judge proxy has finished; each judge is a proxy, in name order.
        assert_eq!(proxies, ["world-model+coarse", "world-model+vlm"]);
        let v = &ranking.comparisons[1];
        let points: Vec<(&str, f64, f64)> = v
            .policies
            .iter()
            .map(|p| (p.policy.as_str(), p.real, p.proxy))
            .collect();
        assert_eq!(
            points,
            [("good", 1.0, 1.0), ("fair", 0.5, 0.5), ("poor", 0.0, 0.0)]
        );
        assert_eq!(v.mmrv.value, Some(0.0));
        assert!((v.pearson.value.unwrap() - 1.0).abs() < 1e-12);
        let c = &ranking.comparisons[0];
        assert_eq!(c.policies.len(), 2);
        // Ranked the wrong way round: every policy's worst swap is the full real gap.
        assert_eq!(c.mmrv.value, Some(1.0));

        let row = |task: &str, policy: &str| {
            r.rows
                .iter()
                .find(|x| x.task_id == task && x.policy == policy)
                .unwrap()
        };
        let fair = &row("t1", "fair").judged_proxy;
        assert_eq!(fair.len(), 1);
        assert_eq!(
            (fair[0].judge.as_str(), &fair[0].success),
            ("vlm", &Proportion::new(1, 2))
        );
        assert_eq!(fair[0].mean_completion, Some(4.0));
        // 4.9 is below the threshold; the failed shard is not a verdict but an error.
        assert_eq!(
            row("t2", "poor").judged_proxy[0].success,
            Proportion::new(0, 1)
        );
        assert_eq!(
            r.judging_errors,
            [(
                "vlm".into(),
                "t2".into(),
                "poor".into(),
                1,
                "HTTP 500".into()
            )]
        );
        let md = r.markdown();
        assert!(md.contains("vlm: 50 % (1/2) (4.0)"), "{md}");
        assert!(md.contains("(ranking-vlm.svg)"), "{md}");
        assert!(
            md.contains("1 imagined rollouts could not be judged"),
            "{md}"
        );
    }

    #[test]
    fn figures_are_named_by_proxy() {
        assert_eq!(ranking_figure(PROXY_SOURCE), RANKING_FIGURE);
        assert_eq!(
            ranking_figure(&judged_source("gpt-4o")),
            "ranking-gpt-4o.svg"
        );
        assert_eq!(ranking_figure(&judged_source("a/b c")), "ranking-a_b_c.svg");
    }
}
