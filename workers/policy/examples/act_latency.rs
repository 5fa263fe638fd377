//! Round-trip latency of `Act` on loopback: the reference server in this process with a policy
//! that answers at once, the blocking client on the main thread, 64×64 frames.
//!
//! `cargo run -p assay-policy --example act_latency [-- CALLS]` (default 200 after 20 warm-up).

use std::sync::Arc;
use std::time::{Duration, Instant};

use assay_model::policy::{Action, EpisodeContext, Policy, PolicyError, PolicyObservation};
use assay_policy::{RemotePolicy, ServerInfo, serve};

struct Fixed;

impl Policy for Fixed {
    fn reset(&mut self, _: &EpisodeContext) -> Result<(), PolicyError> {
        Ok(())
    }
    fn act(&mut self, _: &PolicyObservation) -> Result<Vec<Action>, PolicyError> {
        Ok(vec![[0.1, 0.0, -0.05, 0.0]; 4])
    }
}

fn main() {
    let calls: usize = std::env::args()
        .nth(1)
        .map(|n| n.parse().expect("CALLS: a number"))
        .unwrap_or(200);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    let listener = rt
        .block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))
        .expect("bind");
    let url = format!("http://{}", listener.local_addr().expect("addr"));
    let factory: assay_policy::PolicyFactory = Arc::new(|| Ok(Box::new(Fixed) as Box<dyn Policy>));
    rt.spawn(serve(
        listener,
        factory,
        ServerInfo::default(),
        None,
        std::future::pending(),
    ));
    let mut policy =
        RemotePolicy::connect(&url, Duration::from_secs(5), rt.handle().clone()).expect("connect");
    policy
        .reset(&EpisodeContext {
            task_id: "latency".into(),
            seed: 0,
            instruction: String::new(),
            arm: None,
        })
        .expect("reset");
    let mut obs =
        PolicyObservation::legacy(0, 64, 64, vec![100; 64 * 64 * 3], [0.0, 0.0, 0.2, 0.0]);
    let mut times = Vec::with_capacity(calls);
    for i in 0..20 + calls {
        obs.step = i as u32;
        let start = Instant::now();
        policy.act(&obs).expect("act");
        if i >= 20 {
            times.push(start.elapsed().as_secs_f64() * 1e6);
        }
    }
    times.sort_by(f64::total_cmp);
    let at = |p: f64| times[((times.len() - 1) as f64 * p).round() as usize];
    println!(
        "Act round trip, 64x64 RGB, {calls} calls: median {:.0} us, p90 {:.0} us, p99 {:.0} us, min {:.0} us",
        at(0.5),
        at(0.9),
        at(0.99),
        times[0]
    );
}
