//! `--max-seconds` and `--max-memory` for the bake commands: a bake over either ends with an
//! error naming the budget and the stage it was in, and writes nothing.
//!
//! Done here, around the bake, with no change to `bounce_core`: [`Budget::watch`] wraps the
//! bake's [`Progress`] so that every stage start and every row finished checks the time (the
//! cooperative check, which names the exact stage), and a watchdog thread checks time and peak
//! memory every [`POLL`], for the stretches that report nothing (voxelisation, the BVH build,
//! a single long row). Either check ends the process: core's stages have no way to be
//! cancelled, and a bake over budget is to end now, not at the next stage boundary.
//!
//! No partial output: a bake holds everything in memory until it writes, and the budget is
//! disarmed ([`BudgetGuard::disarm`]) before the file is written, so the process never ends
//! inside `write_atomic` (whose temporary file would stay behind); writing is not counted.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Result, bail};
use bounce_core::bake::{Progress, Stage};
use clap::Args;

use super::summary::human_bytes;
use crate::memory::peak_rss_bytes;

/// How often the watchdog looks at the clock and at peak memory.
const POLL: Duration = Duration::from_millis(50);

/// The budget options, shared by `bake`, `bake transport` and `bake merge`.
#[derive(Args, Debug, Clone, Default)]
pub struct BudgetArgs {
    /// End the bake with an error once it has run this many seconds (fractions allowed), naming
    /// the stage it was in; nothing is written. Writing the file is not counted.
    #[arg(long, value_name = "S")]
    pub max_seconds: Option<f64>,
    /// End the bake with an error once the process's peak resident memory passes this, naming
    /// the stage it was in; nothing is written. Bytes, or with a unit: 512MiB, 2GiB (also K, M,
    /// G, KiB; all powers of 1024).
    #[arg(long, value_name = "BYTES|NMiB", value_parser = parse_bytes)]
    pub max_memory: Option<u64>,
}

/// `4096`, `512MiB`, `2G`, `1.5GiB`: a byte count, units in powers of 1024.
pub fn parse_bytes(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (number, unit) = t.split_at(split);
    let scale: u64 = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1,
        "k" | "kib" | "kb" => 1 << 10,
        "m" | "mib" | "mb" => 1 << 20,
        "g" | "gib" | "gb" => 1 << 30,
        "t" | "tib" | "tb" => 1 << 40,
        other => {
            return Err(format!(
                "unknown unit '{other}' in '{s}' (bytes, or KiB, MiB, GiB, TiB)"
            ));
        }
    };
    let value: f64 = number
        .parse()
        .map_err(|_| format!("'{s}' is not a byte count (e.g. 1073741824, 512MiB, 2GiB)"))?;
    let bytes = value * scale as f64;
    if bytes.is_nan() || bytes < 1.0 || bytes >= u64::MAX as f64 {
        return Err(format!("'{s}' must be at least one byte"));
    }
    Ok(bytes as u64)
}

/// A bake's budget, checked.
#[derive(Debug, Clone, Copy, Default)]
pub struct Budget {
    max_seconds: Option<f64>,
    max_memory: Option<u64>,
}

impl BudgetArgs {
    pub fn budget(&self) -> Result<Budget> {
        if let Some(s) = self.max_seconds
            && (!s.is_finite() || s <= 0.0)
        {
            bail!("--max-seconds must be a positive number of seconds, got {s}");
        }
        Ok(Budget {
            max_seconds: self.max_seconds,
            max_memory: self.max_memory,
        })
    }
}

/// What the checks share: the clock, the stage now running, and whether they may still act.
struct Shared {
    budget: Budget,
    start: Instant,
    stage: Mutex<&'static str>,
    /// Held while the process is being ended, and by `disarm`: once `disarm` returns, no check
    /// ends the process.
    armed: Mutex<bool>,
    /// Tells the watchdog to stop.
    done: AtomicBool,
}

impl Shared {
    /// Ends the process if the budget is spent; `memory` also reads peak memory (a file read,
    /// too slow for every row).
    fn check(&self, memory: bool) {
        let over = self.over(memory);
        let Some(reason) = over else { return };
        let Ok(armed) = self.armed.lock() else { return };
        if !*armed {
            return;
        }
        let stage = self.stage.lock().map(|s| *s).unwrap_or("unknown");
        // The binary's error format (main's `error: ...`), with exit status 1 as for any error.
        eprintln!("error: bake stopped in stage \"{stage}\": {reason}; nothing was written");
        std::process::exit(1);
    }

    fn over(&self, memory: bool) -> Option<String> {
        let elapsed = self.start.elapsed().as_secs_f64();
        if let Some(max) = self.budget.max_seconds
            && elapsed > max
        {
            return Some(format!("it ran {elapsed:.2} s, over --max-seconds {max}"));
        }
        if memory
            && let Some(max) = self.budget.max_memory
            && let Some(peak) = peak_rss_bytes()
            && peak > max
        {
            return Some(format!(
                "its peak memory reached {}, over --max-memory {} ({max} bytes)",
                human_bytes(peak),
                human_bytes(max)
            ));
        }
        None
    }
}

/// A running budget: the progress wrapper and the watchdog. Dropping it stops the watchdog and
/// disarms it.
pub struct BudgetGuard<'a> {
    shared: Arc<Shared>,
    inner: &'a dyn Progress,
    watchdog: Option<std::thread::JoinHandle<()>>,
}

impl Budget {
    pub fn is_set(&self) -> bool {
        self.max_seconds.is_some() || self.max_memory.is_some()
    }

    /// Starts the clock and the watchdog; report the bake's progress to the result, which
    /// passes it on to `inner`.
    pub fn watch(self, inner: &dyn Progress) -> BudgetGuard<'_> {
        let shared = Arc::new(Shared {
            budget: self,
            start: Instant::now(),
            stage: Mutex::new("start"),
            armed: Mutex::new(true),
            done: AtomicBool::new(false),
        });
        let watchdog = self.is_set().then(|| {
            let shared = shared.clone();
            std::thread::spawn(move || {
                while !shared.done.load(Ordering::Relaxed) {
                    shared.check(true);
                    std::thread::sleep(POLL);
                }
            })
        });
        BudgetGuard {
            shared,
            inner,
            watchdog,
        }
    }
}

impl BudgetGuard<'_> {
    /// Names a step of the command's own outside core's stages (packing the model).
    pub fn step(&self, name: &'static str) {
        if let Ok(mut s) = self.shared.stage.lock() {
            *s = name;
        }
        self.shared.check(true);
    }

    /// From here on no check ends the process: the caller is about to write its output.
    pub fn disarm(mut self) {
        self.stop();
    }

    fn stop(&mut self) {
        if let Ok(mut armed) = self.shared.armed.lock() {
            *armed = false;
        }
        self.shared.done.store(true, Ordering::Relaxed);
        if let Some(w) = self.watchdog.take() {
            let _ = w.join();
        }
    }
}

impl Drop for BudgetGuard<'_> {
    fn drop(&mut self) {
        self.stop();
    }
}

impl Progress for BudgetGuard<'_> {
    fn begin(&self, stage: Stage, total: u64) {
        if let Ok(mut s) = self.shared.stage.lock() {
            *s = stage.name();
        }
        self.shared.check(true);
        self.inner.begin(stage, total);
    }

    fn advance(&self, n: u64) {
        self.shared.check(false);
        self.inner.advance(n);
    }

    fn end(&self, stage: Stage, seconds: f64) {
        self.inner.end(stage, seconds);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn byte_counts_and_units() {
        assert_eq!(parse_bytes("4096"), Ok(4096));
        assert_eq!(parse_bytes("512MiB"), Ok(512 << 20));
        assert_eq!(parse_bytes("2G"), Ok(2 << 30));
        assert_eq!(parse_bytes("1.5 GiB"), Ok(3 << 29));
        assert_eq!(parse_bytes("64k"), Ok(64 << 10));
        assert!(parse_bytes("0").is_err());
        assert!(parse_bytes("MiB").is_err());
        assert!(parse_bytes("12 parsecs").is_err());
        assert!(parse_bytes("-5").is_err());
    }
}
