//! The cross-family ablation (`assay_model::proxy::ProxyConfig::cross_family_ablation`): for
//! each family of ranked ladder policies, a video model of the proxy's settings trained on the
//! world model's training clips and the **other** families' ranked clips, which imagines that
//! family's episodes closed loop; a frame judge of its own, trained as the proxy's is (the
//! training episodes' real frames and their replays in this model), calls each one done or not.
//! The paper's setting — a world model that has seen rollouts of policies never ranked with it —
//! with the other family's rollouts as those policies. Only clips reach the fit: no ranked
//! episode's outcome does, and no family is ever imagined by a model that saw its own episodes.

use assay_model::clip::Clip;
use assay_model::policy::EpisodeContext;
use assay_model::proxy::{CrossFamilyFit, CrossFamilyVerdict, ProxyConfig, ProxyEpisode};
use tch::Device;

use super::{JudgeFit, PolicyLoader, Ranked, TrainingEpisodes, action_test, fit_judge, imagine};
use crate::imagination;
use crate::video_model;
use crate::world_model::WorldModelError;

/// The ablation's world models and, per ranked episode (same order), its verdict (`None` for
/// an episode of no family, or of a family no other family was ranked beside).
pub(super) struct Ablation {
    pub fits: Vec<CrossFamilyFit>,
    pub verdicts: Vec<Option<CrossFamilyVerdict>>,
}

/// What the ablation reads of the proxy's request.
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

/// Runs the ablation; with fewer than two ranked families there is nothing to do.
pub(super) fn run(inputs: &Inputs<'_>) -> Result<Ablation, WorldModelError> {
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
    let mut ablation = Ablation {
        fits: Vec::new(),
        verdicts: vec![None; eval.len()],
    };
    let families = families(eval);
    if families.len() < 2 {
        return Ok(ablation);
    }
    for family in &families {
        let others: Vec<String> = families
            .iter()
            .filter(|f| *f != family)
            .map(|f| (*f).to_owned())
            .collect();
        let mut clips: Vec<Clip> = world_clips.to_vec();
        clips.extend(
            eval.iter()
                .zip(eval_clips)
                .filter(|(e, _)| !e.family.is_empty() && e.family != *family)
                .map(|(_, c)| c.clone()),
        );
        let mut no_checkpoints = |_: u64, _: &[u8]| Ok::<(), String>(());
        let (world, fit) =
            video_model::fit(&config.video, &clips, device, None, &mut no_checkpoints)?;
        // Its own judge: the proxy's learned what the main model's replays look like.
        let JudgeFit {
            judge, accuracy, ..
        } = fit_judge(&world, training, config, device)?;
        let judge_one = |f: &[u8]| judge.probability_of(&[f])[0];
        let own: Vec<usize> = (0..eval.len())
            .filter(|&i| eval[i].family == *family)
            .collect();
        let action_test = action_test(
            &world,
            own.iter().map(|&i| (&eval[i], &eval_clips[i])).collect(),
        )?;
        for &i in &own {
            let start = imagination::start_of(&eval_clips[i], &eval_ctx[i]);
            let ranked = Ranked {
                episode: &eval[i],
                context: &eval_ctx[i],
                start: &start,
            };
            let what = "cross-family ablation, ";
            let rollout = imagine(&world, policies, &ranked, &judge_one, config, None, what)?;
            ablation.verdicts[i] = Some(CrossFamilyVerdict {
                p_success: rollout.p_success,
                success: rollout.done_by_judge,
                imagined_frames: rollout.frames.len() as u32 + 1,
            });
        }
        tracing::info!(
            family,
            trained_with = ?others,
            clips = clips.len(),
            "cross-family ablation: a family imagined"
        );
        ablation.fits.push(CrossFamilyFit {
            family: (*family).to_owned(),
            trained_with: others,
            train_clips: clips.len() as u32,
            final_train_loss: fit.final_train_loss,
            judge_train_accuracy: Some(accuracy),
            action_test,
        });
    }
    Ok(ablation)
}
