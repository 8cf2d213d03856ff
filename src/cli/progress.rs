//! Progress of the long commands on standard error: the stage that runs, how far it is and the
//! elapsed time, so that a user sees the command is alive. Standard output (the report) is left
//! alone.
//!
//! One line per stage at its start and end, and at most one every [`INTERVAL`] between: plain
//! lines, no carriage returns or escape codes, so that a log or a CI capture of standard error
//! reads the same as a terminal. They are printed whether or not standard error is a terminal
//! (a command run with `2>log` or in CI is where a stalled stage is hardest to tell from a slow
//! one); `--quiet` turns them off.

use std::fmt::Display;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use facepose_eval::progress::{Observer, Phase, Progress};

/// The least time between two lines of one stage (its start and end lines aside).
pub const INTERVAL: Duration = Duration::from_secs(2);

/// `--quiet`, for the commands that print progress.
#[derive(clap::Args)]
pub struct QuietArg {
    /// Print no progress on standard error (by default: each stage as it starts and ends, how
    /// far it is every 2 s, the elapsed time). Errors still print; standard output is the
    /// same either way.
    #[arg(long, short)]
    pub quiet: bool,
}

/// Prints progress lines on standard error (nothing with `--quiet`). An [`Observer`] of the
/// core's computations, and the commands' own stages through [`Reporter::stage`] and
/// [`Reporter::count`].
pub struct Reporter {
    start: Instant,
    quiet: bool,
    state: Mutex<State>,
}

/// The stage being counted.
struct State {
    label: String,
    /// When it started and when its last line was printed.
    started: Instant,
    printed: Instant,
}

impl Reporter {
    pub fn new(quiet: &QuietArg) -> Self {
        let now = Instant::now();
        Reporter {
            start: now,
            quiet: quiet.quiet,
            state: Mutex::new(State {
                label: String::new(),
                started: now,
                printed: now,
            }),
        }
    }

    /// A stage of the command that is not counted (loading a file, writing the report): one
    /// line.
    pub fn stage(&self, what: impl Display) {
        if self.quiet {
            return;
        }
        let mut s = self.lock();
        s.label.clear();
        self.line(&what.to_string());
    }

    /// `done` of `total` `unit` of the stage `label`: a line when the stage starts (a label
    /// other than the last one's), when it ends (`done == total`, with its duration), and at
    /// most every [`INTERVAL`] between.
    pub fn count(&self, label: &str, done: usize, total: usize, unit: &str) {
        if self.quiet {
            return;
        }
        let mut s = self.lock();
        let now = Instant::now();
        let fresh = s.label != label;
        if fresh {
            s.label.clear();
            s.label.push_str(label);
            s.started = now;
        }
        let end = done >= total;
        if !(fresh || end || now.duration_since(s.printed) >= INTERVAL) {
            return;
        }
        s.printed = now;
        let percent = (100 * done.min(total)).checked_div(total).unwrap_or(100);
        let took = if end && !fresh {
            format!(", {:.1} s", now.duration_since(s.started).as_secs_f64())
        } else {
            String::new()
        };
        self.line(&format!(
            "{label}: {done}/{total} {unit} ({percent}%){took}"
        ));
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        // A panic elsewhere while printing leaves the state usable: it is only labels and times.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn line(&self, text: &str) {
        eprintln!("[{:6.1} s] {text}", self.start.elapsed().as_secs_f64());
    }
}

impl Observer for Reporter {
    fn observe(&self, p: Progress) {
        if self.quiet {
            return;
        }
        let (label, unit) = match p.phase {
            Phase::PaperTraining => (
                "paper protocol: Table 1, training stage (the mean shape's views)".to_string(),
                "poses",
            ),
            Phase::PaperTesting => (
                "paper protocol: Table 1, testing stage (the test shapes' views)".to_string(),
                "poses",
            ),
            Phase::PaperRobustness => (
                "paper protocol: robustness".to_string(),
                "(condition, method) pairs",
            ),
            Phase::Sfm {
                condition,
                conditions,
            } => (
                format!(
                    "structure from motion: condition {}/{conditions}",
                    condition + 1
                ),
                "shapes",
            ),
            Phase::HprGrid => ("HPR over the pose grid".to_string(), "poses"),
        };
        self.count(&label, p.done, p.total, unit);
    }
}
