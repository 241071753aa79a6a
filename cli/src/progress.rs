//! Bake progress on the terminal: one bar per stage with a row count, a spinner otherwise, and a
//! plain line per finished stage so logs of non-interactive runs still show where time went.

use std::sync::Mutex;
use std::time::Duration;

use bounce_core::bake::{Progress, Stage};
use indicatif::{ProgressBar, ProgressStyle};

pub struct TermProgress {
    bar: Mutex<Option<ProgressBar>>,
    quiet: bool,
}

impl TermProgress {
    pub fn new(quiet: bool) -> Self {
        TermProgress {
            bar: Mutex::new(None),
            quiet,
        }
    }
}

impl Progress for TermProgress {
    fn begin(&self, stage: Stage, total: u64) {
        if self.quiet {
            return;
        }
        let bar = if total > 0 {
            let bar = ProgressBar::new(total);
            bar.set_style(
                ProgressStyle::with_template(
                    "{prefix:>14} [{bar:40}] {pos}/{len} rows  {elapsed_precise} eta {eta}",
                )
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> "),
            );
            bar
        } else {
            let bar = ProgressBar::new_spinner();
            bar.enable_steady_tick(Duration::from_millis(120));
            bar
        };
        bar.set_prefix(stage.name());
        if let Ok(mut slot) = self.bar.lock() {
            *slot = Some(bar);
        }
    }

    fn advance(&self, n: u64) {
        if let Ok(slot) = self.bar.lock()
            && let Some(bar) = slot.as_ref()
        {
            bar.inc(n);
        }
    }

    fn end(&self, stage: Stage, seconds: f64) {
        if self.quiet {
            return;
        }
        if let Ok(mut slot) = self.bar.lock()
            && let Some(bar) = slot.take()
        {
            bar.finish_and_clear();
        }
        eprintln!("{:>14}  {seconds:8.2} s", stage.name());
    }
}
