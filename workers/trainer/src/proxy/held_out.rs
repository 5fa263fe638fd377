//! World models that never saw the policies they imagine, trained with other ranked policies'
//! episodes: the cross-family ablation (`assay_model::proxy::ProxyConfig::cross_family_ablation`)
//! and cross-fitting (`ProxyConfig::cross_fit_folds`). Both deal the ranked episodes into parts;
//! per part, a video model of the proxy's settings is trained on the world model's training
//! clips and the **other** parts' ranked clips, a frame judge of its own is trained as the
//! proxy's (the training episodes' real frames and their replays in this model), and the model
//! imagines the part's episodes closed loop until that judge calls them done. The paper's
//! setting — a world model that has seen rollouts of learned policies never ranked with it.
//! Only clips reach the fits: no ranked episode's outcome does, and no episode is ever imagined
//! by a model that saw its policy's episodes.
//!
//! - **Cross-family** (an ablation): one part per family of ranked ladder policies.
//! - **Cross-fitting** (a proxy): the ranked policies dealt into `cross_fit_folds` folds, each
//!   family's in turn in order of first appearance (the k-th policy of a family goes to fold
//!   k mod folds), so every fold holds policies of every family and each model sees siblings
//!   of the policies it imagines.

use assay_model::clip::Clip;
use assay_model::policy::EpisodeContext;
use assay_model::proxy::{
    ActionTest, CrossFamilyFit, CrossFitFold, HeldOutVerdict, ProxyConfig, ProxyEpisode,
};
use tch::Device;

use super::{
    JudgeFit, Judging, PolicyLoader, Ranked, TrainingEpisodes, action_test, fit_judge, imagine,
};
use crate::imagination;
use crate::video_model;
use crate::world_model::WorldModelError;

/// What the held-out models read of the proxy's request.
pub(super) struct Inputs<'a> {
    pub policies: &'a PolicyLoader<'a>,
    /// The main world model's training clips.
    pub world_clips: &'a [Clip],
    /// The training episodes each model's frame judge learns from.
    pub training: &'a TrainingEpisodes<'a>,
    pub eval: &'a [ProxyEpisode],
    pub eval_clips: &'a [Clip],
    pub eval_ctx: &'a [EpisodeContext],
    pub config: &'a ProxyConfig,
    pub device: Device,
}

/// A part's model: what it learned from and how it did.
struct Fitted {
    train_clips: u32,
    final_train_loss: f64,
    judge_train_accuracy: f64,
    action_test: Option<ActionTest>,
}

/// Trains the model of the part `own` (indices of ranked episodes) on the training clips and
/// the ranked clips of `seen`, and its judge; imagines `own`'s episodes into `verdicts`.
/// `what` names the model in errors and logs.
fn held_out(
    inputs: &Inputs<'_>,
    own: &[usize],
    seen: &[usize],
    verdicts: &mut [Option<HeldOutVerdict>],
    what: &str,
) -> Result<Fitted, WorldModelError> {
    let Inputs {
        policies,
        world_clips,
        training,
        eval,
        eval_clips,
        eval_ctx,
        config,
        device,
    } = *inputs;
    let mut clips: Vec<Clip> = world_clips.to_vec();
    clips.extend(seen.iter().map(|&i| eval_clips[i].clone()));
    let mut no_checkpoints = |_: u64, _: &[u8]| Ok::<(), String>(());
    let (world, fit) = video_model::fit(&config.video, &clips, device, None, &mut no_checkpoints)?;
    // Its own judge: the proxy's learned what the main model's replays look like.
    let JudgeFit {
        judge, accuracy, ..
    } = fit_judge(&world, training, config, device)?;
    let judge_one = |f: &[u8]| judge.probability_of(&[f])[0];
    let action_test = action_test(
        &world,
        own.iter().map(|&i| (&eval[i], &eval_clips[i])).collect(),
    )?;
    for &i in own {
        let start = imagination::start_of(&eval_clips[i], &eval_ctx[i]);
        let ranked = Ranked {
            episode: &eval[i],
            context: &eval_ctx[i],
            start: &start,
        };
        let judging = Judging {
            frames: &judge_one,
            objects: None,
            leak_at: None,
        };
        let rollout = imagine(&world, policies, &ranked, &judging, config, what)?;
        verdicts[i] = Some(HeldOutVerdict {
            p_success: rollout.p_success,
            success: rollout.done_by_judge,
            imagined_frames: rollout.frames.len() as u32 + 1,
        });
    }
    Ok(Fitted {
        train_clips: clips.len() as u32,
        final_train_loss: fit.final_train_loss,
        judge_train_accuracy: accuracy,
        action_test,
    })
}

/// The ranked families in order of first appearance.
fn families(eval: &[ProxyEpisode]) -> Vec<&str> {
    let mut out: Vec<&str> = Vec::new();
    for e in eval {
        if !e.family.is_empty() && !out.contains(&e.family.as_str()) {
            out.push(&e.family);
        }
    }
    out
}

/// The cross-family ablation's models and, per ranked episode (same order), its verdict
/// (`None` for an episode of no family, or of a family no other family was ranked beside).
pub(super) fn cross_family(
    inputs: &Inputs<'_>,
) -> Result<(Vec<CrossFamilyFit>, Vec<Option<HeldOutVerdict>>), WorldModelError> {
    let eval = inputs.eval;
    let mut verdicts = vec![None; eval.len()];
    let mut fits = Vec::new();
    let families = families(eval);
    if families.len() < 2 {
        return Ok((fits, verdicts));
    }
    for family in &families {
        let others: Vec<String> = families
            .iter()
            .filter(|f| *f != family)
            .map(|f| (*f).to_owned())
            .collect();
        let (own, seen): (Vec<usize>, Vec<usize>) = (0..eval.len())
            .filter(|&i| !eval[i].family.is_empty())
            .partition(|&i| eval[i].family == *family);
        let what = "cross-family ablation, ";
        let fitted = held_out(inputs, &own, &seen, &mut verdicts, what)?;
        tracing::info!(
            family,
            trained_with = ?others,
            clips = fitted.train_clips,
            "cross-family ablation: a family imagined"
        );
        fits.push(CrossFamilyFit {
            family: (*family).to_owned(),
            trained_with: others,
            train_clips: fitted.train_clips,
            final_train_loss: fitted.final_train_loss,
            judge_train_accuracy: Some(fitted.judge_train_accuracy),
            action_test: fitted.action_test,
        });
    }
    Ok((fits, verdicts))
}

/// The fold of each ranked policy (`folds` of them): each family's policies in turn, in order
/// of first appearance (policies of no family form one family of their own).
fn folds_of(eval: &[ProxyEpisode], folds: u32) -> Vec<(&str, u32)> {
    let mut out: Vec<(&str, u32)> = Vec::new();
    let mut dealt: Vec<(&str, u32)> = Vec::new();
    for e in eval {
        if out.iter().any(|(p, _)| *p == e.policy) {
            continue;
        }
        let n = match dealt.iter_mut().find(|(f, _)| *f == e.family) {
            Some((_, n)) => n,
            None => {
                dealt.push((&e.family, 0));
                &mut dealt.last_mut().expect("just pushed").1
            }
        };
        out.push((&e.policy, *n % folds));
        *n += 1;
    }
    out
}

/// Cross-fitting's models (one per fold that has policies) and, per ranked episode (same
/// order), its verdict (`None` when only one policy is ranked: no other policy's episodes).
pub(super) fn cross_fit(
    inputs: &Inputs<'_>,
    folds: u32,
) -> Result<(Vec<CrossFitFold>, Vec<Option<HeldOutVerdict>>), WorldModelError> {
    let eval = inputs.eval;
    let mut verdicts = vec![None; eval.len()];
    let mut fits = Vec::new();
    let assigned = folds_of(eval, folds);
    if assigned.len() < 2 {
        return Ok((fits, verdicts));
    }
    let fold_of = |e: &ProxyEpisode| {
        assigned
            .iter()
            .find(|(p, _)| *p == e.policy)
            .map_or(0, |(_, k)| *k)
    };
    for fold in 0..folds {
        let (own, seen): (Vec<usize>, Vec<usize>) =
            (0..eval.len()).partition(|&i| fold_of(&eval[i]) == fold);
        if own.is_empty() {
            continue;
        }
        let names = |fold_wanted: bool| -> Vec<String> {
            assigned
                .iter()
                .filter(|(_, k)| (*k == fold) == fold_wanted)
                .map(|(p, _)| (*p).to_owned())
                .collect()
        };
        let what = format!("cross-fitting, fold {fold}, ");
        let fitted = held_out(inputs, &own, &seen, &mut verdicts, &what)?;
        tracing::info!(
            fold,
            clips = fitted.train_clips,
            "cross-fitting: a fold imagined"
        );
        fits.push(CrossFitFold {
            fold,
            policies: names(true),
            trained_with: names(false),
            train_clips: fitted.train_clips,
            final_train_loss: fitted.final_train_loss,
            judge_train_accuracy: fitted.judge_train_accuracy,
            action_test: fitted.action_test,
        });
    }
    Ok((fits, verdicts))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn episode(policy: &str, family: &str) -> ProxyEpisode {
        ProxyEpisode {
            task_id: "t".into(),
            policy: policy.into(),
            seed: 0,
            clip: String::new(),
            instruction: String::new(),
            success: None,
            budget_steps: 1,
            family: family.into(),
        }
    }

    #[test]
    fn each_familys_policies_are_dealt_in_turn_so_every_fold_holds_every_family() {
        let eval = [
            episode("u250", "unet"),
            episode("u500", "unet"),
            episode("t250", "transformer"),
            episode("u250", "unet"),
            episode("u1000", "unet"),
            episode("t500", "transformer"),
            episode("kit", ""),
            episode("u2000", "unet"),
        ];
        assert_eq!(
            folds_of(&eval, 2),
            [
                ("u250", 0),
                ("u500", 1),
                ("t250", 0),
                ("u1000", 0),
                ("t500", 1),
                ("kit", 0),
                ("u2000", 1),
            ]
        );
        assert_eq!(folds_of(&eval, 3)[3], ("u1000", 2));
    }
}
