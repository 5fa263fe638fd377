//! A ranking at a 7-D, two-camera interface (an end-effector-delta policy with a scene and a
//! wrist camera): the proxy trains Assay's video model on clips at that interface — or connects
//! to a PyTorch model served over `assay.v1.WorldModel` by the kit's example — and the ranked
//! policies act inside it, closed loop, shown both cameras and the 8-float state, their 7-D
//! chunks driving the model.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};

use assay_model::clip::Clip;
use assay_model::policy::{EpisodeContext, Policy, PolicyError, PolicyObservation};
use assay_model::proxy::{ExternalWorldModel, ProxyConfig, ProxyEpisode, ProxyResult};
use assay_model::video::{PixelLoss, VideoModelConfig, WorldModelKind};
use assay_model::world::{WorldError, WorldModelService};
use assay_trainer::proxy::{ProxyRequest, run_proxy};
use tch::Device;

mod common;
use common::{SEVEN, two_camera_clip, two_camera_episodes};

/// Moves the square by `dx` every step in 7-D chunks of 2.
struct Mover {
    dx: f32,
}

impl Policy for Mover {
    fn reset(&mut self, _: &EpisodeContext) -> Result<(), PolicyError> {
        Ok(())
    }
    fn act_any(&mut self, obs: &PolicyObservation) -> Result<Vec<Vec<f32>>, PolicyError> {
        let shown: Vec<(u32, u32)> = obs.images.iter().map(|i| (i.width, i.height)).collect();
        if shown != [(32, 32), (16, 16)] || obs.state.len() != 8 {
            return Err(PolicyError::BadAnswer(format!(
                "shown {shown:?} and {} floats of state",
                obs.state.len()
            )));
        }
        Ok(vec![vec![self.dx, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]; 2])
    }
    fn interface(&self) -> assay_model::interface::Interface {
        assay_model::interface::Interface::parse_args(SEVEN).unwrap()
    }
}

/// The ranked policies, by names the proxy can parse (the loader below builds them).
const RIGHT: &str = "remote:url=http://127.0.0.1:1";
const LEFT: &str = "remote:url=http://127.0.0.1:2";

fn episode(policy: &str, seed: u64, success: Option<bool>) -> ProxyEpisode {
    ProxyEpisode {
        task_id: "t".into(),
        policy: policy.into(),
        seed,
        clip: format!("clips/{policy}-{seed}"),
        instruction: "move the square right".into(),
        success,
        budget_steps: 24 * 8,
        family: String::new(),
    }
}

/// Training episodes: the square ends right of where it started (a success) or not.
fn training() -> (Vec<ProxyEpisode>, Vec<Clip>) {
    let clips = two_camera_episodes(0);
    let episodes = clips
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let x = |t: usize| c.proprio[t * 8];
            episode("oracle", i as u64, Some(x(c.len() - 1) > x(0) + 0.2))
        })
        .collect();
    (episodes, clips)
}

/// The ranked policies' real episodes (of which only the first frames reach the proxy).
fn ranked() -> (Vec<ProxyEpisode>, Vec<Clip>) {
    let mut episodes = Vec::new();
    let mut clips = Vec::new();
    for (policy, dx) in [(RIGHT, 2), (LEFT, -2)] {
        for seed in 0..2 {
            episodes.push(episode(policy, seed, None));
            clips.push(two_camera_clip(12 + 2 * seed as i32, 14, &[(dx, 0); 8]));
        }
    }
    (episodes, clips)
}

fn config(external: Option<ExternalWorldModel>) -> ProxyConfig {
    let mut c = ProxyConfig {
        model: WorldModelKind::Video,
        video: VideoModelConfig {
            depth: 8,
            action_embed: 32,
            image_size: 32,
            pixel_loss: PixelLoss::L2,
            steps: 600,
            checkpoint_every: 0,
            ..Default::default()
        },
        judge_steps: 200,
        external,
        ..Default::default()
    };
    c.world_model.image_size = 32;
    c
}

fn rank(config: &ProxyConfig, url: Option<&str>) -> ProxyResult {
    let (train, train_clips) = training();
    let (eval, eval_clips) = ranked();
    let policies = |name: &str| -> Result<Box<dyn Policy>, PolicyError> {
        Ok(Box::new(Mover {
            dx: if name == RIGHT { 0.25 } else { -0.25 },
        }))
    };
    let rt = tokio::runtime::Runtime::new().unwrap();
    let world_models =
        |server: &ExternalWorldModel| -> Result<Box<dyn WorldModelService>, WorldError> {
            assert_eq!(Some(server.url.as_str()), url);
            assay_policy::world_model::connect(&server.url, server.timeout_ms, rt.handle())
        };
    run_proxy(
        &ProxyRequest {
            group: "g",
            policies: &policies,
            world_models: &world_models,
            train: &train,
            train_clips: &train_clips,
            eval: &eval,
            eval_clips: &eval_clips,
            config,
            device: Device::Cpu,
            diagnostics_beside: true,
        },
        None,
        &mut |_, _| Ok(()),
    )
    .unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn seven_d_two_camera_policies_are_ranked_inside_assay_s_video_model() {
    let r = rank(&config(None), None);
    assert!(
        r.world_model_name.contains("'wrist_image' 16x16"),
        "{}",
        r.world_model_name
    );
    assert_eq!(r.predictions.len(), 4);
    assert!(r.predictions.iter().all(|p| p.imagined_frames >= 2));
    // The action test ran with the clips' 7-D actions (true, another episode's, zero).
    let test = r.action_test.as_ref().expect("the action test");
    assert!(test.true_actions_mse > 0.0 && test.shuffled_actions_mse > 0.0);
    let mean = |policy: &str| {
        let p: Vec<f64> = r
            .predictions
            .iter()
            .filter(|p| p.policy == policy)
            .map(|p| p.p_success)
            .collect();
        p.iter().sum::<f64>() / p.len() as f64
    };
    // Trained on clips where moving right is the task, the judge reads the imagined frames of
    // the policy that moves right as done (0.999 here) and the other's as not (0.002).
    assert!(
        mean(RIGHT) > mean(LEFT) + 0.5,
        "moving right (the task) must look better than moving left: {} vs {}",
        mean(RIGHT),
        mean(LEFT)
    );
}

/// The kit's PyTorch video model, served at the 7-D, two-camera interface.
struct Served {
    child: Child,
    url: String,
}

impl Drop for Served {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn serve_torch(declare: &str) -> Served {
    let repo = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let python = std::env::var("ASSAY_LEROBOT_PYTHON").unwrap_or_else(|_| {
        let out = Command::new(repo.join("scripts/setup-lerobot"))
            .stderr(Stdio::inherit())
            .output()
            .unwrap();
        assert!(out.status.success(), "scripts/setup-lerobot failed");
        String::from_utf8(out.stdout).unwrap().trim().to_owned()
    });
    let mut child = Command::new(python)
        .arg(repo.join("python/assay-policy-kit/examples/torch_video_model.py"))
        .args(["serve", "--port", "0", "--size", "32", "--declare", declare])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let mut first = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    let url = first
        .trim()
        .strip_prefix("listening on ")
        .unwrap_or_else(|| panic!("the PyTorch model did not start: {first:?}"))
        .to_owned();
    Served { child, url }
}

#[test]
fn seven_d_two_camera_policies_are_ranked_inside_a_served_pytorch_model() {
    let served =
        serve_torch("ee_delta/ee_pos+ee_quat+gripper/image:scene@32x32+wrist_image:wrist@16x16");
    let external = ExternalWorldModel {
        url: served.url.clone(),
        timeout_ms: 60_000,
    };
    let r = rank(&config(Some(external)), Some(&served.url));
    assert!(
        r.world_model_name.starts_with("torch-video-model"),
        "{}",
        r.world_model_name
    );
    assert_eq!(r.world_model.steps, 0);
    assert_eq!(r.predictions.len(), 4);
    // Every imagined step came back with both cameras at their sizes and an 8-float state (the
    // client refuses an answer without them, and the policy fails its episode when shown
    // anything else). Its weights are untrained: what it predicts is not the point here.
    assert!(r.predictions.iter().all(|p| p.imagined_frames >= 2));
    let test = r.action_test.as_ref().expect("the action test");
    assert!(test.true_actions_mse > 0.0);
}
