//! Progress of long commands on stderr: a line redrawn in place on a
//! terminal, a plain line every ten seconds otherwise (logs, CI), and one
//! at the end.

use std::io::{IsTerminal, Write};
use std::time::Instant;

/// Seconds between plain progress lines when stderr is not a terminal.
const PLAIN_EVERY_S: f64 = 10.0;

/// Reports `done / total` for one task.
pub struct Progress {
    label: String,
    total: usize,
    start: Instant,
    terminal: bool,
    /// When the last plain line was written.
    last_line: Option<Instant>,
}

impl Progress {
    /// Starts reporting `label` out of `total` steps.
    pub fn new(label: &str, total: usize) -> Self {
        Progress {
            label: label.to_string(),
            total: total.max(1),
            start: Instant::now(),
            terminal: std::io::stderr().is_terminal(),
            last_line: None,
        }
    }

    /// Records that `done` steps are finished.
    pub fn set(&mut self, done: usize) {
        let elapsed = self.start.elapsed().as_secs_f64();
        let rate = done as f64 / elapsed.max(1e-9);
        let line = format!(
            "{}: {done}/{} ({:.0}%, {rate:.1}/s)",
            self.label,
            self.total,
            100.0 * done as f64 / self.total as f64
        );
        let mut err = std::io::stderr().lock();
        if self.terminal {
            let _ = write!(err, "\r{line}\x1b[K");
            if done >= self.total {
                let _ = writeln!(err);
            }
        } else {
            let due = self
                .last_line
                .is_none_or(|t| t.elapsed().as_secs_f64() >= PLAIN_EVERY_S);
            if due || done >= self.total {
                self.last_line = Some(Instant::now());
                let _ = writeln!(err, "{line}");
            }
        }
    }
}

/// Stages of a command whose work has no count to show (loading a map,
/// scoring it), announced on stderr as they start, with the time since
/// the command began: long silences on slow devices get an explanation.
pub struct Stages {
    label: &'static str,
    start: Instant,
}

impl Stages {
    /// Starts the clock for command `label`.
    pub fn new(label: &'static str) -> Self {
        Stages {
            label,
            start: Instant::now(),
        }
    }

    /// Announces the next stage.
    pub fn start(&self, what: impl std::fmt::Display) {
        let _ = writeln!(
            std::io::stderr().lock(),
            "{} [{:>6.1} s] {what}",
            self.label,
            self.start.elapsed().as_secs_f64()
        );
    }
}
