//! What the cli's test binaries (`cli`, `deploy`, `browser`) share: the `bounce` binary, the demo
//! scene, running a command with the check that it did not panic, and `bounce serve` as a child
//! process on loopback ports.

// Each test binary uses its own part of this module.
#![allow(dead_code)]

use std::collections::VecDeque;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::{Arc, Mutex};

pub fn bounce() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bounce"))
}

pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The embedded demo scene.
pub fn cornell() -> PathBuf {
    repo().join("assets/cornell-box/scene.gltf")
}

/// Runs `cmd` to the end. A panic exits with 101, and every failure a user can cause must be a
/// clean error (exit 1) instead, so 101 fails the test whatever the test expected.
pub fn run(cmd: &mut Command) -> Output {
    let out = cmd.output().expect("the command runs");
    assert_ne!(
        out.status.code(),
        Some(101),
        "{cmd:?} panicked:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

pub fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// A command that needs a GPU adapter (lavapipe will do) ran: `true` when it succeeded; `false`
/// when it found no adapter and `BOUNCE_ALLOW_NO_GPU=1` allows skipping (the test returns). Any
/// other failure fails the test; a missing adapter does too, naming `scripts/test`.
pub fn gpu_ran(out: &Output, what: &str) -> bool {
    if out.status.success() {
        return true;
    }
    let err = stderr(out);
    // The engine's "no GPU adapter found" and the renderer's "needs a GPU adapter".
    if err.contains("GPU adapter") {
        bounce_testkit::missing::<()>(bounce_testkit::Tool::GpuAdapter, format!("{what}: {err}"));
        return false;
    }
    panic!("{what} failed:\n{err}");
}

/// `run`, and it succeeded.
pub fn ok(cmd: &mut Command) -> Output {
    let out = run(cmd);
    assert!(out.status.success(), "{cmd:?} failed:\n{}", stderr(&out));
    out
}

/// `run`, and it failed cleanly (exit status 1) with `says` in the message.
pub fn refused(cmd: &mut Command, says: &str) {
    let out = run(cmd);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{cmd:?}: {err}");
    assert!(err.contains(says), "{cmd:?} should say '{says}':\n{err}");
}

/// The last `lines` lines read from `pipe`, read to its end on a thread of their own (which is
/// finished once the writer has closed it).
pub fn keep_tail(
    pipe: impl std::io::Read + Send + 'static,
    lines: usize,
) -> (Arc<Mutex<VecDeque<String>>>, std::thread::JoinHandle<()>) {
    let kept = Arc::new(Mutex::new(VecDeque::new()));
    let tail = kept.clone();
    let reader = std::thread::spawn(move || {
        for line in BufReader::new(pipe).lines() {
            let Ok(line) = line else { break };
            let mut tail = tail.lock().unwrap();
            tail.push_back(line);
            if tail.len() > lines {
                tail.pop_front();
            }
        }
    });
    (kept, reader)
}

/// `bounce serve` with the CPU engine on free loopback ports, scenes from `scenes`, sessions
/// stored in `data`, no periodic reload: add options (`--token`) to it, then `ServeChild::spawn`.
pub fn serve_command(scenes: &Path, data: &Path, http: &str) -> Command {
    let mut cmd = bounce();
    cmd.args(["serve", "--engine", "cpu", "--grpc", "127.0.0.1:0"])
        .args(["--http", http, "--reload-every", "0"])
        .arg("--scenes")
        .arg(scenes)
        .arg("--data-dir")
        .arg(data);
    cmd
}

/// How many of the server's last stderr lines a failure shows.
const STDERR_LINES: usize = 40;

/// A `bounce serve` child process with the addresses it printed; killed (SIGKILL) and reaped on
/// drop.
pub struct ServeChild {
    child: Child,
    pub grpc: String,
    pub http: String,
    stderr: Arc<Mutex<VecDeque<String>>>,
}

impl ServeChild {
    /// Starts `cmd` (a `serve_command`) and waits until it has printed where it listens. If it
    /// exits first, the test fails with the end of its stderr.
    pub fn spawn(mut cmd: Command) -> ServeChild {
        let mut child = cmd
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("bounce serve starts");
        // Drained all the time, not only on failure: a full pipe would stall the server's logging.
        let (stderr, _) = keep_tail(child.stderr.take().expect("stderr is piped"), STDERR_LINES);
        let stdout = child.stdout.take().expect("stdout is piped");
        let (mut grpc, mut http) = (None, None);
        for line in BufReader::new(stdout).lines() {
            let Ok(line) = line else { break };
            let line = line.trim_start();
            let first = |rest: &str| rest.split_whitespace().next().map(str::to_owned);
            if let Some(rest) = line.strip_prefix("gRPC  ") {
                grpc = first(rest);
            } else if let Some(rest) = line.strip_prefix("HTTP  ") {
                http = first(rest);
            }
            if grpc.is_some() && http.is_some() {
                break;
            }
        }
        let mut serve = ServeChild {
            child,
            grpc: String::new(),
            http: String::new(),
            stderr,
        };
        match (grpc, http) {
            (Some(grpc), Some(http)) => {
                serve.grpc = grpc;
                serve.http = http;
                serve
            }
            _ => {
                let status = serve.child.wait();
                // The reader thread has seen the last line once the process is gone.
                std::thread::sleep(std::time::Duration::from_millis(100));
                panic!(
                    "bounce serve did not print its addresses ({status:?}); its stderr ends:\n{}",
                    serve.stderr_tail()
                );
            }
        }
    }

    pub fn stderr_tail(&self) -> String {
        let tail = self.stderr.lock().unwrap();
        tail.iter().cloned().collect::<Vec<_>>().join("\n")
    }

    /// SIGKILL: nothing of the server's shutdown runs, as in a crash.
    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for ServeChild {
    fn drop(&mut self) {
        self.kill();
    }
}
