//! Progress of long commands on stderr: a line redrawn in place on a
//! terminal, a plain line every ten seconds otherwise (logs, CI), and one
//! at the end.

use std::io::{IsTerminal, Write};
use std::time::Instant;

/// A status line on stderr: redrawn in place on a terminal (at most ten
/// times a second), a plain line every ten seconds otherwise (logs, CI).
pub struct StatusLine {
    terminal: bool,
    /// When the last line was shown.
    last: Option<Instant>,
}

impl Default for StatusLine {
    fn default() -> Self {
        StatusLine {
            terminal: std::io::stderr().is_terminal(),
            last: None,
        }
    }
}

impl StatusLine {
    /// Whether a line shown now would appear (a final line always does):
    /// lines that cost something to compose are composed only when due.
    pub fn due(&self) -> bool {
        let every = if self.terminal { 0.1 } else { 10.0 };
        self.last.is_none_or(|t| t.elapsed().as_secs_f64() >= every)
    }

    /// Shows `line` (call when [`StatusLine::due`], or for the last line).
    pub fn show(&mut self, line: &str) {
        self.last = Some(Instant::now());
        let mut err = std::io::stderr().lock();
        if self.terminal {
            let _ = write!(err, "\r{line}\x1b[K");
        } else {
            let _ = writeln!(err, "{line}");
        }
    }

    /// Ends the redrawn line on a terminal.
    pub fn finish(&self) {
        if self.terminal && self.last.is_some() {
            let _ = writeln!(std::io::stderr().lock());
        }
    }
}

/// Reports `done / total` for one task.
pub struct Progress {
    label: String,
    total: usize,
    start: Instant,
    line: StatusLine,
}

impl Progress {
    /// Starts reporting `label` out of `total` steps.
    pub fn new(label: &str, total: usize) -> Self {
        Progress {
            label: label.to_string(),
            total: total.max(1),
            start: Instant::now(),
            line: StatusLine::default(),
        }
    }

    /// Records that `done` steps are finished.
    pub fn set(&mut self, done: usize) {
        let last = done >= self.total;
        if !(last || self.line.due()) {
            return;
        }
        let elapsed = self.start.elapsed().as_secs_f64();
        let rate = done as f64 / elapsed.max(1e-9);
        self.line.show(&format!(
            "{}: {done}/{} ({:.0}%, {rate:.1}/s)",
            self.label,
            self.total,
            100.0 * done as f64 / self.total as f64
        ));
        if last {
            self.line.finish();
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
            "{} [{:>6.1} s] {}",
            self.label,
            self.start.elapsed().as_secs_f64(),
            // Paths and names in it come from the user or a log.
            latentam::text::shown(&what.to_string())
        );
    }
}
