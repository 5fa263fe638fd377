//! The terminal's view of a run: one progress bar per kind of work the batch has (episodes,
//! judging, training), each with its own ETA, and a line per event — or, with `--quiet`, a status
//! line per change instead of bars. Implements `assay_run::follow::Observer`.

use assay_run::follow::{Event, Observer};
use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};

/// Bars on stderr (hidden when quiet).
pub struct Terminal {
    quiet: bool,
    bars: MultiProgress,
    episodes: ProgressBar,
    judging: ProgressBar,
    training: ProgressBar,
    /// Which bars the batch has: judging, training.
    shown: (bool, bool),
}

impl Terminal {
    pub fn new(quiet: bool) -> Self {
        let bars = if quiet {
            MultiProgress::with_draw_target(ProgressDrawTarget::hidden())
        } else {
            MultiProgress::new()
        };
        let style =
            |template: &str| ProgressStyle::with_template(template).expect("progress template");
        let episodes = ProgressBar::new(0);
        episodes.set_style(style(
            "{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} episodes, eta {eta}  {msg}",
        ));
        let judging = ProgressBar::new(0);
        judging.set_style(style(
            "  judging      {bar:40} {pos}/{len} episodes judged, eta {eta}  {msg}",
        ));
        let training = ProgressBar::new(0);
        training.set_style(style(
            "  training     {bar:40} {pos}/{len} trainer jobs, eta {eta}  {msg}",
        ));
        Self {
            quiet,
            bars,
            episodes,
            judging,
            training,
            shown: (false, false),
        }
    }

    /// Shown from the start when the batch will have such work, in this order.
    fn start(&mut self, judging: bool, training: bool) {
        self.bars.add(self.episodes.clone());
        if judging {
            self.bars.add(self.judging.clone());
        }
        if training {
            self.bars.add(self.training.clone());
        }
        self.shown = (judging, training);
    }

    fn status(&self, st: &assay_proto::v1::BatchStatus, steps: f64, frames: f64) {
        let finished = st.shards_done + st.shards_failed + st.shards_cancelled;
        self.episodes.set_length(u64::from(st.shards_total));
        self.episodes.set_position(u64::from(finished));
        if st.judge_total > 0 {
            self.judging.set_length(u64::from(st.judge_total));
            self.judging
                .set_position(u64::from(st.judge_done + st.judge_failed));
            self.judging
                .set_message(format!("{} failed", st.judge_failed));
        }
        if st.trainer_total > 0 {
            self.training.set_length(u64::from(st.trainer_total));
            self.training
                .set_position(u64::from(st.trainer_done + st.trainer_failed));
            self.training
                .set_message(format!("{} failed", st.trainer_failed));
        }
        self.episodes.set_message(format!(
            "{} ok, {} failed, {} running, {} workers, {steps:.0} steps/s, {frames:.0} frames/s",
            st.successes, st.shards_failed, st.shards_running, st.workers_connected,
        ));
        if self.quiet {
            eprintln!("{}", crate::print::status_line(st));
        }
    }

    fn finish(&self) {
        self.episodes.finish();
        if self.shown.0 {
            self.judging.finish();
        }
        if self.shown.1 {
            self.training.finish();
        }
    }
}

impl Observer for Terminal {
    fn event(&mut self, event: Event<'_>) {
        match event {
            Event::Imported {
                pipeline,
                path,
                import,
                folder,
            } => {
                out!("{}", import.report());
                outln!(
                    "imported {} of {} {pipeline} task(s) from {} ({} not imported; mapping in {})",
                    import.specs().len(),
                    import.tasks.len(),
                    path.display(),
                    assay_run::imports::failed(import),
                    folder.join("import-report.json").display()
                );
            }
            Event::ClusterStarted { description } => eprintln!("{description}"),
            Event::Submitted { response: r } => {
                crate::print::rejected(&r.rejected);
                eprintln!(
                    "batch {}: {} tasks accepted, {} rejected, {} episodes",
                    r.batch_id,
                    r.accepted_tasks,
                    r.rejected.len(),
                    r.shards
                );
            }
            Event::Resumed { batch_id, run_dir } => eprintln!(
                "batch {batch_id}: going on from the job store in {} (finished episodes are kept)",
                run_dir.display()
            ),
            Event::Following { judging, training } => self.start(judging, training),
            Event::Status {
                status,
                steps_per_s,
                frames_per_s,
            } => self.status(status, steps_per_s, frames_per_s),
            Event::Process { line } => self.bars.suspend(|| eprintln!("{line}")),
            Event::Followed => self.finish(),
            Event::Watching {
                dir,
                poll_ms,
                corpus,
            } => eprintln!(
                "watching {} (every {poll_ms} ms); corpus report in {}",
                dir.display(),
                corpus.display()
            ),
            Event::Rejected { errors } => crate::print::rejected(errors),
            Event::Handled { entry, models } => {
                eprintln!("{}", assay_run::corpus::summary(entry, models));
            }
            _ => {}
        }
    }
}
