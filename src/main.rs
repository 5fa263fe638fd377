//! `assay`: the command-line entry point. Thin: each subcommand lives in `cmd/` (its arguments,
//! one library call, what it prints), the logic in the workspace's libraries — `assay-run` for
//! running batches and reading their results.

#[macro_use]
mod print;
mod args;
mod cmd;
mod config;
mod logging;
mod progress;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "assay",
    version,
    about = "Evaluate generated robot tasks and policies on a cluster of real processes"
)]
struct Cli {
    /// Log format on stderr: pretty or json. Filter with ASSAY_LOG (e.g. ASSAY_LOG=debug).
    #[arg(
        long,
        global = true,
        env = "ASSAY_LOG_FORMAT",
        default_value = "pretty"
    )]
    log_format: String,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a batch end to end on a local cluster (coordinator + N sim workers) and write a report.
    Eval(cmd::eval::Args),
    /// Continuous evaluation: evaluate every batch (sub-folder of task specs) that lands in a
    /// folder, skip repeats by content hash, report each batch's marginal diversity.
    #[cfg(feature = "trainer")]
    Watch(cmd::watch::Args),
    /// Check this machine for what Assay's roles need (Vulkan, libtorch, embedding models,
    /// zenoh, shared memory, judge endpoints) and say what to fix.
    Doctor(cmd::doctor::Args),
    /// Run the coordinator (one per cluster).
    Coordinator(cmd::coordinator::Args),
    /// Run a worker process with one or more roles.
    Worker(cmd::worker::Args),
    /// Submit a batch of task specs to a running coordinator.
    Submit(cmd::submit::Args),
    /// Show the status of one batch, or list all batches.
    Status(cmd::status::Args),
    /// Fetch a batch's report (report.json, report.md).
    Report(cmd::report::Args),
    /// Write a finished run's results in another tool's format (LeRobotDataset, TensorBoard).
    Export(cmd::export::Args),
    /// Cancel a batch.
    Cancel(cmd::status::CancelArgs),
    /// Live view of a cluster: workers' rates and batches' progress, from telemetry.
    Top(cmd::top::Args),
    /// Keys derived from the cluster token: a role's (worker, submitter, viewer) or a service's.
    Token(cmd::token::Args),
    /// Check task specs without running them.
    Validate(cmd::validate::Args),
    /// Read a GenSim, RoboGen or BBSEA batch as task specs, with the per-task mapping report.
    Import(cmd::import::Args),
    /// Agreement of judges with human ratings from a CSV: Pearson r, MAE, r/MAE, Spearman, Kendall.
    Agreement(cmd::agreement::Args),
    /// Rank policies by a proxy (world model, simulator) against real success from a success
    /// table: R and R_S per policy, Pearson r, MMRV, Spearman, Kendall; the correlation plot.
    Rank(cmd::rank::Args),
    /// Text diversity (eq. 1) of groups of texts from a YAML/JSON file, per embedding model, and
    /// the marginal diversity a new batch adds to a corpus.
    #[cfg(feature = "trainer")]
    Diversity(cmd::diversity::Args),
    /// Print a JSON Schema: of task spec v1 (`task`, the default) or of report.json (`report`).
    Schema {
        #[arg(default_value = "task", value_parser = ["task", "report"])]
        of: String,
    },
    /// Benchmarks on the peer reference scene (compare with shared/bench/peers/peers.py).
    Bench(cmd::bench::Args),
    /// Serve a policy over the assay.v1.Policy gRPC service, or check a policy or policy server.
    Policy(cmd::policy::Args),
    /// Publish or subscribe to a frame stream on this node's frame bus (tests, diagnostics).
    #[command(hide = true)]
    Frames(cmd::frames::Args),
}

fn main() -> std::process::ExitCode {
    // Layered configuration: the TOML file < ASSAY_* variables < flags (src/config.rs).
    let args: Vec<std::ffi::OsString> = std::env::args_os().collect();
    let running = config::subcommand(&args);
    let command = match config::layer(
        Cli::command(),
        config::file(&args).as_deref(),
        running.as_deref(),
    ) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("error: {e}");
            return std::process::ExitCode::FAILURE;
        }
    };
    let matches = match command.clone().try_get_matches_from(&args) {
        Ok(m) => m,
        Err(e) => {
            if let Some(blame) =
                config::blame(config::file(&args).as_deref(), running.as_deref(), &e)
            {
                eprintln!("error: {blame}");
            }
            e.exit()
        }
    };
    let cli = match Cli::from_arg_matches(&matches) {
        Ok(cli) => cli,
        Err(e) => e.exit(),
    };
    logging::init(&cli.log_format);
    assay_run::local::die_with_parent();
    let result = match cli.command {
        Command::Eval(a) => {
            let resolved = config::resolved(
                &command,
                &matches,
                "eval",
                config::file(&args).as_deref(),
                &args,
            );
            cmd::eval::run(a, Some(resolved))
        }
        #[cfg(feature = "trainer")]
        Command::Watch(a) => cmd::watch::run(a),
        Command::Doctor(a) => cmd::doctor::run(a),
        Command::Coordinator(a) => cmd::coordinator::run(a),
        Command::Worker(a) => cmd::worker::run(a),
        Command::Submit(a) => cmd::submit::run(a),
        Command::Status(a) => cmd::status::run(a),
        Command::Report(a) => cmd::report::run(a),
        Command::Export(a) => cmd::export::run(a),
        Command::Cancel(a) => cmd::status::cancel(a),
        Command::Top(a) => cmd::top::run(a),
        Command::Token(a) => cmd::token::run(a),
        Command::Validate(a) => cmd::validate::run(a),
        Command::Import(a) => cmd::import::run(a),
        Command::Agreement(a) => cmd::agreement::run(a),
        Command::Rank(a) => cmd::rank::run(a),
        #[cfg(feature = "trainer")]
        Command::Diversity(a) => cmd::diversity::run(a),
        Command::Schema { of } => {
            let schema = match of.as_str() {
                "report" => assay_report::report::json_schema(),
                _ => assay_spec::spec::json_schema(),
            };
            outln!("{}", serde_json::to_string_pretty(&schema).expect("schema"));
            Ok(std::process::ExitCode::SUCCESS)
        }
        Command::Bench(a) => cmd::bench::run(a),
        Command::Frames(a) => cmd::frames::run(a),
        Command::Policy(a) => cmd::policy::run(a),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {}", print::error_chain(&e));
            std::process::ExitCode::FAILURE
        }
    }
}
