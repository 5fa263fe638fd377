//! `assay frames`: publish or subscribe to a frame stream on this node's frame bus, or relay a
//! node's streams to other nodes over gRPC (`assay.v1.Frames`). Used by the multi-process tests
//! and the hand-off benchmark; the work is `assay_run::frames`'.

use std::path::PathBuf;
use std::process::ExitCode;

use assay_run::frames;

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub cmd: Cmd,
}

#[derive(clap::Subcommand)]
pub enum Cmd {
    /// Publish a test pattern (frame number in every byte, sequence number up front).
    Publish {
        #[arg(long)]
        stream: String,
        #[arg(long, default_value_t = 100)]
        count: u64,
        #[arg(long, default_value_t = 640)]
        width: u32,
        #[arg(long, default_value_t = 480)]
        height: u32,
        /// Pause between frames, in microseconds.
        #[arg(long, default_value_t = 1000)]
        interval_us: u64,
    },
    /// Receive frames, check them, and report counts and hand-off latency as JSON.
    Subscribe {
        #[arg(long)]
        stream: String,
        /// Stop after this many frames.
        #[arg(long, default_value_t = 100)]
        count: u64,
        /// Stop after this long without reaching `count`.
        #[arg(long, default_value_t = 30.0)]
        timeout_s: f64,
        /// Written once the subscriber is connected.
        #[arg(long)]
        ready_file: Option<PathBuf>,
        /// Poll without sleeping (lowest latency; uses a whole core).
        #[arg(long)]
        spin: bool,
        /// Receive from a frame relay over gRPC (e.g. http://10.0.0.5:7460) instead of this
        /// node's shared memory. Latency is only meaningful when the relay is on this node.
        #[arg(long)]
        grpc: Option<String>,
        /// Save every RGBA frame as DIR/<episode>-<camera>-<step>.png instead of checking it
        /// against the test pattern (to look at what a worker's render role publishes; shared
        /// memory only).
        #[arg(long)]
        save: Option<PathBuf>,
    },
    /// Serve this node's frame streams to other nodes over gRPC (`assay.v1.Frames`). Frames are
    /// copied out of shared memory only while some client is subscribed.
    Relay {
        /// Streams to serve (repeat the flag).
        #[arg(long, required = true)]
        stream: Vec<String>,
        /// Address to listen on (port 0: any free port).
        #[arg(long, default_value = "127.0.0.1:7460")]
        listen: std::net::SocketAddr,
        /// Written with the address actually bound, once serving.
        #[arg(long)]
        addr_file: Option<PathBuf>,
    },
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    match a.cmd {
        Cmd::Publish {
            stream,
            count,
            width,
            height,
            interval_us,
        } => {
            let sent = frames::publish(&stream, count, (width, height), interval_us)?;
            outln!("{sent}");
            Ok(ExitCode::SUCCESS)
        }
        Cmd::Subscribe {
            stream,
            count,
            timeout_s,
            ready_file,
            spin,
            grpc,
            save,
        } => {
            let (received, ok) = frames::subscribe(&frames::Subscription {
                stream,
                count,
                timeout_s,
                ready_file,
                spin,
                grpc,
                save,
            })?;
            outln!("{received}");
            Ok(if ok {
                ExitCode::SUCCESS
            } else {
                ExitCode::FAILURE
            })
        }
        Cmd::Relay {
            stream,
            listen,
            addr_file,
        } => {
            frames::relay(stream, listen, addr_file)?;
            Ok(ExitCode::SUCCESS)
        }
    }
}
