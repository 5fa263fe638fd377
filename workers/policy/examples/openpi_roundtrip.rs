//! Round-trip latency of Assay's openpi client (`openpi:url=ws://…`) against a running openpi
//! server, with the observation `tests/python/openpi_roundtrip.py` sends openpi's own Python
//! client: "observation/image" and "observation/wrist_image" uint8 [S, S, 3] (random), a float32
//! state of 8, a prompt. Warms up with 20 calls, times N and prints one JSON line.
//!
//! `cargo run -p assay-policy --example openpi_roundtrip -- ws://HOST:PORT [N] [S]`; the side by
//! side run with the Python client is `bench/policies/openpi-roundtrip.sh`.

use std::time::{Duration, Instant};

use assay_model::policy::{
    CameraRequest, CameraSource, EpisodeContext, Interface, NamedImage, Policy, PolicyObservation,
    StatePart,
};
use assay_policy::openpi::OpenPiPolicy;

const WARMUP: usize = 20;

fn main() {
    let mut args = std::env::args().skip(1);
    let url = args
        .next()
        .expect("usage: openpi_roundtrip ws://HOST:PORT [N] [SIZE]");
    let n: usize = args.next().map_or(200, |a| a.parse().expect("N"));
    let size: u32 = args.next().map_or(224, |a| a.parse().expect("SIZE"));
    let camera = |name: &str, source| CameraRequest {
        name: name.into(),
        source,
        width: size,
        height: size,
        depth: false,
    };
    let interface = Interface {
        cameras: vec![
            camera("image", CameraSource::Scene),
            camera("wrist_image", CameraSource::Wrist),
        ],
        state: vec![StatePart::EePos, StatePart::EeQuat, StatePart::Holding],
        ..Interface::default()
    };
    let mut policy = OpenPiPolicy::new(&url, Duration::from_secs(10), None, interface)
        .unwrap_or_else(|e| panic!("{e}"));
    policy
        .reset(&EpisodeContext {
            task_id: "bench".into(),
            seed: 0,
            instruction: "pick up the red cube and put it in the bowl".into(),
            arm: None,
        })
        .unwrap();
    // A fixed pseudo-random image (xorshift), as the Python side draws one from numpy.
    let mut x = 0x9e37_79b9_7f4a_7c15u64;
    let mut noise = |len: usize| -> Vec<u8> {
        (0..len)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                x as u8
            })
            .collect()
    };
    let pixels = (size * size * 3) as usize;
    let images: Vec<NamedImage> = ["image", "wrist_image"]
        .iter()
        .map(|name| NamedImage {
            name: (*name).into(),
            width: size,
            height: size,
            rgb: noise(pixels),
            depth: Vec::new(),
        })
        .collect();
    let mut obs = PolicyObservation::legacy(0, size, size, images[0].rgb.clone(), [0.0; 4]);
    obs.images = images;
    obs.state = vec![0.1, -0.2, 0.3, 0.0, 1.0, 0.0, 0.0, 0.0];
    for _ in 0..WARMUP {
        policy.act_any(&obs).unwrap();
    }
    let mut us: Vec<f64> = (0..n)
        .map(|_| {
            let t = Instant::now();
            let a = policy.act_any(&obs).unwrap();
            std::hint::black_box(a);
            t.elapsed().as_secs_f64() * 1e6
        })
        .collect();
    us.sort_by(f64::total_cmp);
    let q = |p: f64| us[((p * n as f64).ceil() as usize).clamp(1, n) - 1];
    println!(
        "{{\"client\": \"assay openpi client (rust)\", \"n\": {n}, \"median_us\": {:.1}, \"p90_us\": {:.1}, \"p99_us\": {:.1}}}",
        q(0.5),
        q(0.9),
        q(0.99)
    );
}
