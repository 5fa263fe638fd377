//! What a finished batch's proxy world model imagines for its own training episodes: each
//! training clip replayed open loop from its real first frame with its real actions, and again
//! with the hold command (the action's last value at the original interface) zeroed. Writes one
//! PNG per clip — rows: the real frames, the replay, the replay without holding; 8 frames
//! evenly spaced — and prints the last frames' difference between the two replays. A model
//! that draws the held object moving only when it is held shows it in the third row.
//!
//! ```sh
//! sqlite3 OUT/run/jobs.db "SELECT input_json FROM shards WHERE job LIKE 'proxy %'" > /tmp/proxy.json
//! cargo run -p assay-trainer --example replay_hold -- OUT/artifacts /tmp/proxy.json /tmp/replays
//! ```

use std::path::PathBuf;

use assay_model::clip::Clip;
use assay_model::trainer::TrainerJob;
use assay_model::video::WorldModelKind;
use assay_trainer::imagination::{actions_of, mse, replay, sheet_png, start_at};
use assay_trainer::video_model::VideoModel;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 4 {
        return Err("usage: replay_hold ARTIFACTS JOB.json OUT-DIR".into());
    }
    let root = PathBuf::from(&args[1]);
    let job: TrainerJob = serde_json::from_str(&std::fs::read_to_string(&args[2])?)?;
    let out = PathBuf::from(&args[3]);
    std::fs::create_dir_all(&out)?;
    let TrainerJob::Proxy {
        train,
        config,
        world_model,
        ..
    } = job
    else {
        return Err("not a proxy job".into());
    };
    if config.model != WorldModelKind::Video || config.external.is_some() {
        return Err("the proxy's world model is not the built-in video model".into());
    }
    let key = world_model.ok_or("the proxy had no world model fitted ahead")?;
    let model = VideoModel::from_checkpoint(
        &config.video,
        config.video.image_size,
        &std::fs::read(root.join(key))?,
        assay_trainer::default_device(),
    )?;
    for (i, e) in train.iter().enumerate() {
        let clip = Clip::decode(&std::fs::read(root.join(&e.clip))?)?;
        let start = start_at(&clip, 0, &e.task_id, e.seed, "");
        let actions = actions_of(&clip);
        let mut no_hold = actions.clone();
        for a in &mut no_hold {
            if let Some(hold) = a.last_mut() {
                *hold = 0.0;
            }
        }
        let real: Vec<&[u8]> = (1..clip.len()).map(|t| clip.frame(t)).collect();
        let held = replay(&model, &start, &actions)?;
        let unheld = replay(&model, &start, &no_hold)?;
        let n = real.len().min(held.len()).min(unheld.len());
        if n == 0 {
            continue;
        }
        let picks: Vec<usize> = (0..8).map(|k| k * (n - 1) / 7).collect();
        let rows = vec![
            picks.iter().map(|&t| real[t]).collect(),
            picks.iter().map(|&t| held[t].as_slice()).collect(),
            picks.iter().map(|&t| unheld[t].as_slice()).collect(),
        ];
        let sheet = sheet_png(&rows, clip.width as usize, clip.height as usize);
        let name = format!("{i:02}-{}.png", e.policy.replace([':', '=', ',', '/'], "_"));
        std::fs::write(out.join(name), sheet)?;
        println!(
            "{i} {} seed {}: {n} frames, last frames held vs not {:.5}",
            e.policy,
            e.seed,
            mse(&held[n - 1], &unheld[n - 1])
        );
    }
    Ok(())
}
