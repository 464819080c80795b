//! Progress bars (indicatif) for the library's progress reports. Bars draw only on a terminal.

use std::sync::Mutex;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use livebake::progress::Progress;

pub struct Ui {
    quiet: bool,
    bar: Mutex<Option<ProgressBar>>,
}

impl Ui {
    pub fn new(quiet: bool) -> Self {
        Ui { quiet, bar: Mutex::new(None) }
    }

    /// Prints a line of the final summary (stdout), unless quiet.
    pub fn say(&self, line: impl AsRef<str>) {
        if !self.quiet {
            println!("{}", line.as_ref());
        }
    }

    pub fn begin_phase(&self, phase: &str, total: u64) {
        Progress::begin(self, phase, total)
    }

    pub fn reached_at(&self, done: u64) {
        Progress::reached(self, done)
    }

    pub fn end_phase(&self) {
        Progress::end(self)
    }

    /// Shows `line` beside the current phase's bar or spinner.
    pub fn status(&self, line: &str) {
        self.with_bar(|b| {
            if let Some(bar) = b {
                bar.set_message(line.to_string());
            }
        });
    }

    fn with_bar(&self, f: impl FnOnce(&mut Option<ProgressBar>)) {
        if let Ok(mut guard) = self.bar.lock() {
            f(&mut guard);
        }
    }
}

impl Progress for Ui {
    fn begin(&self, phase: &str, total: u64) {
        if self.quiet {
            return;
        }
        let bar = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr_with_hz(10));
        // An unknown amount of work (total 0) gets a spinner and a status line.
        let template = if total == 0 {
            "{spinner} {prefix} {elapsed} {msg}"
        } else {
            "{msg:>18} [{bar:40}] {pos}/{len} ({percent}%) eta {eta}"
        };
        if let Ok(style) = ProgressStyle::with_template(template) {
            bar.set_style(style.progress_chars("=> "));
        }
        bar.set_prefix(phase.to_string());
        bar.set_message(phase.to_string());
        bar.enable_steady_tick(Duration::from_millis(200));
        self.with_bar(|b| *b = Some(bar));
    }

    fn advance(&self, n: u64) {
        self.with_bar(|b| {
            if let Some(bar) = b {
                bar.inc(n);
            }
        });
    }

    fn reached(&self, done: u64) {
        self.with_bar(|b| {
            if let Some(bar) = b
                && done > bar.position()
            {
                bar.set_position(done);
            }
        });
    }

    fn end(&self) {
        self.with_bar(|b| {
            if let Some(bar) = b.take() {
                bar.finish_and_clear();
            }
        });
    }
}
