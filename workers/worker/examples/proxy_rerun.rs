//! Runs a finished batch's world-model proxy again with other settings, on its artifacts: the
//! proxy's trainer job (its input JSON from the store) with a JSON object merged over its
//! `config`, the policies built as the trainer role builds them. Prints one JSON line per
//! prediction and a summary per policy; the simulator's outcomes stay where they are (compare
//! with the batch's report). For measuring the proxy's settings without running the episodes
//! again (`PROXY_RERUN_KEYFRAMES=DIR` also writes each imagined rollout's keyframes there):
//!
//! ```sh
//! sqlite3 out/rank-learned/run/jobs.db "SELECT input_json FROM shards WHERE job LIKE 'proxy %'" > /tmp/proxy.json
//! cargo run -p assay-worker --features trainer --example proxy_rerun -- \
//!     out/rank-learned/artifacts /tmp/proxy.json '{"normalize_actions": false}'
//! ```

use std::collections::BTreeMap;
use std::path::PathBuf;

use assay_model::clip::Clip;
use assay_model::policy::{Policy, PolicyError, PolicySpec};
use assay_model::proxy::ExternalWorldModel;
use assay_model::trainer::TrainerJob;
use assay_trainer::proxy::{ProxyRequest, run_proxy};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        return Err("usage: proxy_rerun ARTIFACTS JOB.json [CONFIG-OVERRIDE-JSON]".into());
    }
    let root = PathBuf::from(&args[1]);
    let job: TrainerJob = serde_json::from_str(&std::fs::read_to_string(&args[2])?)?;
    let TrainerJob::Proxy {
        group,
        train,
        eval,
        config,
        world_model,
    } = job
    else {
        return Err("not a proxy job".into());
    };
    let mut value = serde_json::to_value(&config)?;
    if let Some(over) = args.get(3) {
        merge(&mut value, serde_json::from_str(over)?);
    }
    let config = serde_json::from_value(value)?;
    let load = |keys: Vec<&String>| -> Result<Vec<Clip>, Box<dyn std::error::Error>> {
        keys.into_iter()
            .map(|k| Ok(Clip::decode(&std::fs::read(root.join(k))?)?))
            .collect()
    };
    let train_clips = load(train.iter().map(|e| &e.clip).collect())?;
    let eval_clips = load(eval.iter().map(|e| &e.clip).collect())?;
    let runtime = tokio::runtime::Runtime::new()?;
    let handle = runtime.handle().clone();
    let policies = |name: &str| -> Result<Box<dyn Policy>, PolicyError> {
        let spec = PolicySpec::parse(name).map_err(PolicyError::Load)?;
        assay_policy::load_with(&spec, &root, &handle, assay_worker::diffusion_loader())
    };
    let world_models = |server: &ExternalWorldModel| {
        assay_policy::world_model::connect(&server.url, server.timeout_ms, &handle)
    };
    // The world model fitted ahead of the proxy, when the batch had one: imagining starts from
    // it (a config override that changes its training settings refits, as the trainer does).
    let ahead = world_model
        .map(|k| std::fs::read(root.join(k)))
        .transpose()?;
    let request = ProxyRequest {
        group: &group,
        policies: &policies,
        world_models: &world_models,
        train: &train,
        train_clips: &train_clips,
        eval: &eval,
        eval_clips: &eval_clips,
        config: &config,
        device: assay_trainer::default_device(),
        diagnostics_beside: true,
    };
    let result = match run_proxy(&request, ahead.as_deref(), &mut |_, _| Ok(())) {
        Err(assay_trainer::world_model::WorldModelError::CheckpointRefused(why)) => {
            eprintln!("the world model fitted ahead is refused ({why}); fitting one");
            run_proxy(&request, None, &mut |_, _| Ok(()))?
        }
        other => other?,
    };
    // `PROXY_RERUN_KEYFRAMES=DIR`: each ranked episode's imagined keyframes (the real first
    // frame, then evenly to the verdict's frame) side by side, one PNG per episode: what the
    // model imagined for it.
    if let Some(dir) = std::env::var_os("PROXY_RERUN_KEYFRAMES").map(PathBuf::from) {
        std::fs::create_dir_all(&dir)?;
        let (w, h) = result.imagined_frame_size;
        for (i, (p, frames)) in result
            .predictions
            .iter()
            .zip(&result.imagined_frames)
            .enumerate()
        {
            let row: Vec<&[u8]> = frames.iter().map(|(_, rgb)| rgb.as_slice()).collect();
            let png = assay_trainer::imagination::sheet_png(&[row], w as usize, h as usize);
            let verdict = if p.success { "done" } else { "not-done" };
            std::fs::write(
                dir.join(format!("{i:03}-seed{}-{verdict}.png", p.seed)),
                png,
            )?;
        }
    }
    let mut by_policy: BTreeMap<&str, (u32, u32, f64)> = BTreeMap::new();
    for p in &result.predictions {
        println!("{}", serde_json::to_string(p)?);
        let e = by_policy.entry(&p.policy).or_default();
        e.0 += 1;
        e.1 += u32::from(p.success);
        e.2 += f64::from(p.imagined_frames);
    }
    for (policy, (n, ok, frames)) in by_policy {
        eprintln!(
            "{policy}: predicted {ok}/{n}, mean imagined frames {:.1}",
            frames / f64::from(n)
        );
    }
    eprintln!(
        "world model {}: one-step image MSE {:.5}; action test {:?}; frame judge train accuracy {:.3}; {:.0} s",
        result.world_model_name,
        result.world_model.eval_image_mse,
        result.action_test,
        result.judge_train_accuracy,
        result.seconds
    );
    Ok(())
}

fn merge(into: &mut serde_json::Value, over: serde_json::Value) {
    match (into, over) {
        (serde_json::Value::Object(a), serde_json::Value::Object(b)) => {
            for (k, v) in b {
                merge(a.entry(k).or_insert(serde_json::Value::Null), v);
            }
        }
        (slot, v) => *slot = v,
    }
}
