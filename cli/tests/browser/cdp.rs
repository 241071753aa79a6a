//! A small Chrome DevTools Protocol driver for the browser tests: it launches Debian's headless
//! chromium, talks CDP over its WebSocket, and gives each test page `goto`, `eval`, `wait_for`,
//! screenshots, mouse and key input, and the page's console and errors.
//!
//! One reader task owns the receiving half of the WebSocket: it answers calls by id and logs every
//! event under its session, so an event that arrives before anyone waits for it is not lost. One
//! writer task owns the sending half. Both run on the runtime that launched the browser, so a
//! `Browser` lives and dies within one `#[tokio::test]`.

#![allow(dead_code)] // each test uses part of the driver

use std::collections::{HashMap, VecDeque};
use std::fmt;
use std::os::unix::process::CommandExt;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use base64::Engine as _;
use futures_util::{SinkExt, StreamExt};
use serde_json::{Value, json};
use tokio::sync::{Notify, mpsc, oneshot};
use tokio_tungstenite::tungstenite::Message;

/// How long one CDP call, the launch, or a navigation may take.
pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(30);

/// chromium's flags for this closed, GPU-less sandbox.
const FLAGS: &[&str] = &[
    "--headless=new",
    // Containers (and CI) run as root, where chromium refuses its sandbox.
    "--no-sandbox",
    "--no-first-run",
    "--no-default-browser-check",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-quic",
    "--disable-default-apps",
    "--disable-extensions",
    "--mute-audio",
    // Docker gives /dev/shm 64 MB, where chromium's shared memory runs out; use /tmp instead.
    "--disable-dev-shm-usage",
    // WebGL2 without a GPU: ANGLE on SwiftShader (a CPU Vulkan implementation shipped with
    // chromium, /usr/lib/chromium/libvk_swiftshader.so).
    // --use-angle=swiftshader picks it up front, whatever GPU or driver the machine has, so
    //   every machine renders the same way.
    // --enable-unsafe-swiftshader opts in to WebGL on SwiftShader explicitly: chromium is
    //   removing the silent fallback to it (148 still falls back, logging "Automatic fallback to
    //   software WebGL has been deprecated. Please use the --enable-unsafe-swiftshader flag").
    // No --disable-gpu: it is not needed, and alone it leaves no WebGL at all (chromium 148:
    //   getContext('webgl2') returns null); next to the two flags above it is harmless.
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    // Several pages draw at once (two tabs on one session): none of them may be throttled or
    // paused as a background tab.
    "--disable-background-timer-throttling",
    "--disable-renderer-backgrounding",
    "--disable-backgrounding-occluded-windows",
    "--remote-debugging-port=0",
];

pub enum CdpError {
    /// chromium did not start, or did not open its DevTools port; `stderr` is the tail of its log.
    Launch {
        message: String,
        stderr: String,
    },
    /// The protocol answered a call with an error.
    Protocol {
        method: String,
        code: i64,
        message: String,
    },
    /// No answer (or event) within the time allowed.
    Timeout {
        what: String,
        after: Duration,
    },
    /// The page's JavaScript threw (text, and the stack where there is one).
    Js {
        method: String,
        exception: String,
    },
    /// A navigation failed (`errorText`), or the page crashed.
    Navigation {
        url: String,
        error: String,
    },
    /// The WebSocket closed, or the browser went away.
    Closed(String),
    Other(String),
}

impl fmt::Display for CdpError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CdpError::Launch { message, stderr } => {
                write!(
                    f,
                    "launching chromium: {message}\n--- chromium's stderr (tail) ---\n{stderr}"
                )
            }
            CdpError::Protocol {
                method,
                code,
                message,
            } => {
                write!(f, "CDP {method} failed: {message} (code {code})")
            }
            CdpError::Timeout { what, after } => write!(f, "timed out after {after:?}: {what}"),
            CdpError::Js { method, exception } => {
                write!(f, "{method}: JavaScript threw: {exception}")
            }
            CdpError::Navigation { url, error } => write!(f, "navigating to {url}: {error}"),
            CdpError::Closed(why) => write!(f, "CDP connection closed: {why}"),
            CdpError::Other(why) => f.write_str(why),
        }
    }
}

/// As Display, so that `unwrap()` in a test prints chromium's stderr readably.
impl fmt::Debug for CdpError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Display::fmt(self, f)
    }
}

impl std::error::Error for CdpError {}

/// Where chromium is: `$BOUNCE_CHROMIUM`, else Debian's `/usr/bin/chromium`.
pub fn chromium_path() -> PathBuf {
    std::env::var_os("BOUNCE_CHROMIUM")
        .map_or_else(|| PathBuf::from("/usr/bin/chromium"), PathBuf::from)
}

/// The chromium to test with. Without one this panics (CI must not skip silently), naming
/// `scripts/test`, which installs it, unless `BOUNCE_ALLOW_NO_BROWSER=1`, where it says why on
/// stderr and returns `None`: the caller returns.
pub fn chromium_or_skip() -> Option<PathBuf> {
    let path = chromium_path();
    if path.is_file() {
        return Some(path);
    }
    bounce_testkit::missing(
        bounce_testkit::Tool::Chromium,
        format!("no chromium at {}", path.display()),
    )
}

/// One message from the page's console or log.
#[derive(Clone, Debug, PartialEq)]
pub struct ConsoleEntry {
    /// "log", "info", "warning", "error", "debug", ... (console API types and Log levels).
    pub level: String,
    pub text: String,
}

impl ConsoleEntry {
    pub fn is_error(&self) -> bool {
        matches!(self.level.as_str(), "error" | "assert")
    }
}

/// A CDP event, as logged for its session.
#[derive(Clone, Debug)]
struct Event {
    method: String,
    params: Value,
}

/// Events kept per session; older ones are dropped (nobody waits for them after this many).
const EVENT_LOG_CAP: usize = 4096;

#[derive(Default)]
struct Session {
    /// Events, `first` being the index of `events[0]` in the session's whole history.
    events: Mutex<(u64, VecDeque<Event>)>,
    console: Mutex<Vec<ConsoleEntry>>,
    notify: Notify,
}

impl Session {
    fn cursor(&self) -> u64 {
        let log = self.events.lock().unwrap();
        log.0 + log.1.len() as u64
    }

    fn push(&self, event: Event) {
        if let Some(entry) = console_entry(&event) {
            self.console.lock().unwrap().push(entry);
        }
        let mut log = self.events.lock().unwrap();
        log.1.push_back(event);
        if log.1.len() > EVENT_LOG_CAP {
            log.1.pop_front();
            log.0 += 1;
        }
        drop(log);
        self.notify.notify_waiters();
    }

    /// The first event at or after `since` that `want` accepts.
    fn find(&self, since: u64, want: &dyn Fn(&Event) -> bool) -> Option<Event> {
        let log = self.events.lock().unwrap();
        let skip = since.saturating_sub(log.0) as usize;
        log.1.iter().skip(skip).find(|e| want(e)).cloned()
    }
}

/// The console entry an event makes, if it is one of the console or log events.
fn console_entry(event: &Event) -> Option<ConsoleEntry> {
    let p = &event.params;
    match event.method.as_str() {
        "Runtime.consoleAPICalled" => {
            let args = p["args"].as_array().map(Vec::as_slice).unwrap_or_default();
            let text = args
                .iter()
                .map(remote_object_text)
                .collect::<Vec<_>>()
                .join(" ");
            Some(ConsoleEntry {
                level: p["type"].as_str().unwrap_or("log").to_owned(),
                text,
            })
        }
        "Runtime.exceptionThrown" => Some(ConsoleEntry {
            level: "error".to_owned(),
            text: exception_text(&p["exceptionDetails"]),
        }),
        "Log.entryAdded" => {
            let e = &p["entry"];
            let mut text = e["text"].as_str().unwrap_or_default().to_owned();
            if let Some(url) = e["url"].as_str().filter(|u| !u.is_empty()) {
                text = format!("{text} ({url})");
            }
            Some(ConsoleEntry {
                level: e["level"].as_str().unwrap_or("info").to_owned(),
                text,
            })
        }
        "Inspector.targetCrashed" => Some(ConsoleEntry {
            level: "error".to_owned(),
            text: "the page crashed".to_owned(),
        }),
        _ => None,
    }
}

/// A console argument as text: strings bare, other values as JSON, objects by description.
fn remote_object_text(o: &Value) -> String {
    match (
        &o["value"],
        o["unserializableValue"].as_str(),
        o["description"].as_str(),
    ) {
        (Value::String(s), _, _) => s.clone(),
        (v, _, _) if !v.is_null() => v.to_string(),
        (_, Some(u), _) => u.to_owned(),
        (_, _, Some(d)) => d.to_owned(),
        _ => o["type"].as_str().unwrap_or("undefined").to_owned(),
    }
}

/// `exceptionDetails` as text: the message, the exception (with its stack, for Error objects),
/// and where it was thrown.
fn exception_text(d: &Value) -> String {
    let mut text = d["text"].as_str().unwrap_or("exception").to_owned();
    let exception = &d["exception"];
    if !exception.is_null() {
        text = format!("{text} {}", remote_object_text(exception));
    }
    let has_stack = exception["description"]
        .as_str()
        .is_some_and(|s| s.contains("\n    at "));
    if !has_stack {
        if let Some(frames) = d["stackTrace"]["callFrames"].as_array() {
            for f in frames {
                let name = f["functionName"]
                    .as_str()
                    .filter(|n| !n.is_empty())
                    .unwrap_or("<anonymous>");
                text += &format!(
                    "\n    at {name} ({}:{}:{})",
                    f["url"].as_str().unwrap_or(""),
                    f["lineNumber"],
                    f["columnNumber"]
                );
            }
        }
        if let Some(url) = d["url"].as_str().filter(|u| !u.is_empty()) {
            text += &format!("\n    at {url}:{}:{}", d["lineNumber"], d["columnNumber"]);
        }
    }
    text
}

type Reply = Result<Value, (i64, String)>;

struct Pending {
    session: Option<String>,
    reply: oneshot::Sender<Reply>,
}

/// The shared side of the connection: calls in flight and the sessions' event logs.
struct Conn {
    out: mpsc::UnboundedSender<String>,
    next_id: AtomicU64,
    pending: Mutex<HashMap<u64, Pending>>,
    sessions: Mutex<HashMap<String, Arc<Session>>>,
    /// Why the connection closed, once it has.
    closed: Mutex<Option<String>>,
    timeout: Duration,
}

impl Conn {
    fn session(&self, id: &str) -> Arc<Session> {
        self.sessions
            .lock()
            .unwrap()
            .entry(id.to_owned())
            .or_default()
            .clone()
    }

    /// Sends a call without waiting for its answer (for `Drop`).
    fn send_only(&self, session: Option<&str>, method: &str, params: Value) {
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        let _ = self
            .out
            .send(message(id, session, method, params).to_string());
    }

    async fn call(
        &self,
        session: Option<&str>,
        method: &str,
        params: Value,
        timeout: Duration,
    ) -> Result<Value, CdpError> {
        if let Some(why) = self.closed.lock().unwrap().clone() {
            return Err(CdpError::Closed(format!("{why} (calling {method})")));
        }
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        let (tx, rx) = oneshot::channel();
        self.pending.lock().unwrap().insert(
            id,
            Pending {
                session: session.map(str::to_owned),
                reply: tx,
            },
        );
        if self
            .out
            .send(message(id, session, method, params).to_string())
            .is_err()
        {
            self.pending.lock().unwrap().remove(&id);
            return Err(CdpError::Closed(format!(
                "the writer is gone (calling {method})"
            )));
        }
        match tokio::time::timeout(timeout, rx).await {
            Ok(Ok(Ok(result))) => Ok(result),
            Ok(Ok(Err((code, message)))) => Err(CdpError::Protocol {
                method: method.to_owned(),
                code,
                message,
            }),
            Ok(Err(_)) => {
                let why = self
                    .closed
                    .lock()
                    .unwrap()
                    .clone()
                    .unwrap_or_else(|| "no answer".to_owned());
                Err(CdpError::Closed(format!("{why} (calling {method})")))
            }
            Err(_) => {
                self.pending.lock().unwrap().remove(&id);
                Err(CdpError::Timeout {
                    what: format!("CDP {method}"),
                    after: timeout,
                })
            }
        }
    }

    /// The reader: answers calls, logs events, and fails everything once the socket closes.
    fn dispatch(&self, text: &str) {
        let Ok(msg) = serde_json::from_str::<Value>(text) else {
            return;
        };
        let session = msg["sessionId"].as_str();
        if let Some(id) = msg["id"].as_u64() {
            let Some(p) = self.pending.lock().unwrap().remove(&id) else {
                return;
            };
            let reply = match msg.get("error") {
                Some(e) => {
                    let mut message = e["message"].as_str().unwrap_or("unknown error").to_owned();
                    if let Some(data) = e["data"].as_str() {
                        message = format!("{message}: {data}");
                    }
                    Err((e["code"].as_i64().unwrap_or(0), message))
                }
                None => Ok(msg.get("result").cloned().unwrap_or(Value::Null)),
            };
            let _ = p.reply.send(reply);
            return;
        }
        let Some(method) = msg["method"].as_str() else {
            return;
        };
        let params = msg.get("params").cloned().unwrap_or(Value::Null);
        // A detached or crashed session answers nothing more: fail its calls now, not at timeout.
        let gone = match method {
            "Target.detachedFromTarget" => params["sessionId"].as_str().map(str::to_owned),
            "Inspector.targetCrashed" => session.map(str::to_owned),
            _ => None,
        };
        if let Some(sid) = session {
            self.session(sid).push(Event {
                method: method.to_owned(),
                params,
            });
        }
        if let Some(sid) = gone {
            if method == "Target.detachedFromTarget" {
                self.sessions.lock().unwrap().remove(&sid);
            }
            let mut pending = self.pending.lock().unwrap();
            let ids: Vec<u64> = pending
                .iter()
                .filter(|(_, p)| p.session.as_deref() == Some(&sid))
                .map(|(id, _)| *id)
                .collect();
            for id in ids {
                if let Some(p) = pending.remove(&id) {
                    let _ = p
                        .reply
                        .send(Err((0, format!("the target went away ({method})"))));
                }
            }
        }
    }

    fn close(&self, why: String) {
        self.closed.lock().unwrap().get_or_insert(why);
        // Dropping the senders wakes every caller, which then reads `closed`.
        self.pending.lock().unwrap().clear();
        for s in self.sessions.lock().unwrap().values() {
            s.notify.notify_waiters();
        }
    }
}

fn message(id: u64, session: Option<&str>, method: &str, params: Value) -> Value {
    let mut m = json!({ "id": id, "method": method, "params": params });
    if let Some(s) = session {
        m["sessionId"] = json!(s);
    }
    m
}

/// A headless chromium and the CDP connection to it. Dropping it kills chromium (its whole process
/// group) and removes its profile.
pub struct Browser {
    child: Child,
    profile: Option<tempfile::TempDir>,
    conn: Arc<Conn>,
    stderr: Arc<Mutex<VecDeque<String>>>,
    tasks: Vec<tokio::task::JoinHandle<()>>,
}

/// Lines of chromium's stderr kept for error messages.
const STDERR_LINES: usize = 60;

impl Browser {
    /// Launches chromium (see [`chromium_path`]) headless, with a fresh profile and the flags above.
    /// chromium also dies with the thread that launched it (PR_SET_PDEATHSIG), so a test binary
    /// killed mid-test leaves none behind: launch from the test's own task, not a blocking thread.
    pub async fn launch() -> Result<Browser, CdpError> {
        Self::launch_with(&chromium_path(), &[]).await
    }

    /// Launches the chromium at `path`, with `extra` flags after ours.
    pub async fn launch_with(path: &std::path::Path, extra: &[&str]) -> Result<Browser, CdpError> {
        let launch_err =
            |message: String, stderr: &Arc<Mutex<VecDeque<String>>>| CdpError::Launch {
                message,
                stderr: stderr
                    .lock()
                    .unwrap()
                    .iter()
                    .cloned()
                    .collect::<Vec<_>>()
                    .join("\n"),
            };
        let no_stderr = Arc::new(Mutex::new(VecDeque::new()));
        let profile = tempfile::Builder::new()
            .prefix("bounce-chromium-")
            .tempdir()
            .map_err(|e| launch_err(format!("creating a profile directory: {e}"), &no_stderr))?;
        // chromium's own temporary files (its singleton socket directory, which a killed chromium
        // leaves behind) go inside the profile, so removing the profile removes them too.
        let tmp = profile.path().join("tmp");
        std::fs::create_dir(&tmp)
            .map_err(|e| launch_err(format!("creating {}: {e}", tmp.display()), &no_stderr))?;
        let mut cmd = Command::new(path);
        cmd.env("TMPDIR", &tmp)
            .args(FLAGS)
            .arg(format!("--user-data-dir={}", profile.path().display()))
            .args(extra)
            .arg("about:blank")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            // Its own process group, so Drop kills the renderers and the GPU process with it.
            .process_group(0);
        // SAFETY: prctl is async-signal-safe; nothing else runs between fork and exec.
        // If the test process dies without dropping the Browser (killed, aborted), chromium dies
        // with the thread that launched it instead of lingering.
        unsafe {
            cmd.pre_exec(|| {
                libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL);
                Ok(())
            });
        }
        let mut child = cmd
            .spawn()
            .map_err(|e| launch_err(format!("running {}: {e}", path.display()), &no_stderr))?;

        let (stderr, stderr_reader) =
            crate::common::keep_tail(child.stderr.take().expect("stderr is piped"), STDERR_LINES);

        // Reap and clean up on every error path below.
        let fail = |mut child: Child, message: String| {
            kill_group(&mut child);
            launch_err(message, &stderr)
        };

        // chromium writes "<port>\n<path>" to DevToolsActivePort once it listens.
        let port_file = profile.path().join("DevToolsActivePort");
        let start = Instant::now();
        let url = loop {
            if let Ok(text) = std::fs::read_to_string(&port_file) {
                let mut lines = text.lines();
                if let (Some(port), Some(path)) = (lines.next(), lines.next())
                    && port.parse::<u16>().is_ok()
                    && path.starts_with('/')
                {
                    break format!("ws://127.0.0.1:{port}{path}");
                }
            }
            match child.try_wait() {
                Ok(Some(status)) => {
                    // Let the stderr thread read the last lines (up to the pipe's end).
                    let start = Instant::now();
                    while !stderr_reader.is_finished() && start.elapsed() < Duration::from_secs(1) {
                        tokio::time::sleep(Duration::from_millis(10)).await;
                    }
                    return Err(fail(
                        child,
                        format!("{} exited at launch ({status})", path.display()),
                    ));
                }
                Ok(None) => {}
                Err(e) => return Err(fail(child, format!("waiting for chromium: {e}"))),
            }
            if start.elapsed() > DEFAULT_TIMEOUT {
                return Err(fail(
                    child,
                    format!("no {} after {DEFAULT_TIMEOUT:?}", port_file.display()),
                ));
            }
            tokio::time::sleep(Duration::from_millis(25)).await;
        };

        let config = tokio_tungstenite::tungstenite::protocol::WebSocketConfig::default()
            .max_message_size(Some(512 << 20))
            .max_frame_size(Some(512 << 20));
        let socket = match tokio::time::timeout(
            DEFAULT_TIMEOUT,
            tokio_tungstenite::connect_async_with_config(url.as_str(), Some(config), true),
        )
        .await
        {
            Ok(Ok((socket, _))) => socket,
            Ok(Err(e)) => return Err(fail(child, format!("connecting to {url}: {e}"))),
            Err(_) => return Err(fail(child, format!("connecting to {url}: timed out"))),
        };
        let (mut sink, mut stream) = socket.split();
        let (out, mut out_rx) = mpsc::unbounded_channel::<String>();
        let conn = Arc::new(Conn {
            out,
            next_id: AtomicU64::new(1),
            pending: Mutex::new(HashMap::new()),
            sessions: Mutex::new(HashMap::new()),
            closed: Mutex::new(None),
            timeout: DEFAULT_TIMEOUT,
        });
        let writer = tokio::spawn(async move {
            while let Some(text) = out_rx.recv().await {
                if sink.send(Message::text(text)).await.is_err() {
                    break;
                }
            }
        });
        let reader_conn = conn.clone();
        let reader = tokio::spawn(async move {
            let why = loop {
                match stream.next().await {
                    Some(Ok(Message::Text(text))) => reader_conn.dispatch(&text),
                    Some(Ok(Message::Close(frame))) => {
                        break format!("chromium closed the WebSocket ({frame:?})");
                    }
                    Some(Ok(_)) => {}
                    Some(Err(e)) => break format!("reading the WebSocket: {e}"),
                    None => break "the WebSocket ended".to_owned(),
                }
            };
            reader_conn.close(why);
        });
        Ok(Browser {
            child,
            profile: Some(profile),
            conn,
            stderr,
            tasks: vec![writer, reader],
        })
    }

    /// chromium's process id (the browser process; its renderers share its process group).
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// The profile (`--user-data-dir`), removed on drop.
    pub fn profile_dir(&self) -> &std::path::Path {
        self.profile
            .as_ref()
            .expect("the profile lives until drop")
            .path()
    }

    /// The last lines chromium wrote to stderr.
    pub fn stderr_tail(&self) -> String {
        self.stderr
            .lock()
            .unwrap()
            .iter()
            .cloned()
            .collect::<Vec<_>>()
            .join("\n")
    }

    /// A browser-level CDP call (no session).
    pub async fn call(&self, method: &str, params: Value) -> Result<Value, CdpError> {
        self.conn
            .call(None, method, params, self.conn.timeout)
            .await
    }

    /// A new tab of `width`×`height` CSS pixels at device scale factor 1, on about:blank, with the
    /// Page, Runtime and Log domains on.
    pub async fn new_page(&self, width: u32, height: u32) -> Result<Page, CdpError> {
        let target = self
            // Each page its own window, so every page is visible and runs its animation frames
            // (a background tab's requestAnimationFrame is paused).
            .call(
                "Target.createTarget",
                json!({ "url": "about:blank", "newWindow": true }),
            )
            .await?;
        let target_id = target["targetId"]
            .as_str()
            .ok_or_else(|| CdpError::Other(format!("Target.createTarget gave {target}")))?
            .to_owned();
        let attached = self
            .call(
                "Target.attachToTarget",
                json!({ "targetId": target_id, "flatten": true }),
            )
            .await?;
        let session_id = attached["sessionId"]
            .as_str()
            .ok_or_else(|| CdpError::Other(format!("Target.attachToTarget gave {attached}")))?
            .to_owned();
        let page = Page {
            session: self.conn.session(&session_id),
            conn: self.conn.clone(),
            session_id,
            target_id,
            buttons: Mutex::new(0),
        };
        page.call("Page.enable", json!({})).await?;
        page.call("Page.setLifecycleEventsEnabled", json!({ "enabled": true }))
            .await?;
        page.call("Runtime.enable", json!({})).await?;
        page.call("Log.enable", json!({})).await?;
        page.call(
            "Emulation.setDeviceMetricsOverride",
            json!({ "width": width, "height": height, "deviceScaleFactor": 1, "mobile": false }),
        )
        .await?;
        Ok(page)
    }
}

/// Kills chromium's process group and reaps the browser process.
fn kill_group(child: &mut Child) {
    let pid = child.id() as libc::pid_t;
    // SAFETY: plain syscall; the group id is the child's pid (process_group(0)).
    unsafe {
        libc::kill(-pid, libc::SIGKILL);
    }
    let _ = child.kill();
    let _ = child.wait();
}

impl Drop for Browser {
    fn drop(&mut self) {
        for t in &self.tasks {
            t.abort();
        }
        kill_group(&mut self.child);
        self.conn.close("the browser was dropped".to_owned());
        if let Some(profile) = self.profile.take() {
            let _ = profile.close();
        }
    }
}

/// Mouse buttons for [`Page::mouse`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MouseButton {
    Left,
    Middle,
    Right,
}

impl MouseButton {
    fn name(self) -> &'static str {
        match self {
            MouseButton::Left => "left",
            MouseButton::Middle => "middle",
            MouseButton::Right => "right",
        }
    }

    /// The `buttons` bit, as in DOM MouseEvent.buttons.
    fn bit(self) -> u32 {
        match self {
            MouseButton::Left => 1,
            MouseButton::Right => 2,
            MouseButton::Middle => 4,
        }
    }
}

/// What [`Page::mouse`] does at its point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MouseKind {
    /// Moves there (a drag while a button is down).
    Move,
    Down(MouseButton),
    Up(MouseButton),
    /// A wheel turn, in CSS pixels (positive `dy` scrolls down / zooms out in most viewers).
    Wheel {
        dx: f64,
        dy: f64,
    },
}

/// One tab, attached through a flat session.
pub struct Page {
    conn: Arc<Conn>,
    session: Arc<Session>,
    session_id: String,
    target_id: String,
    /// Buttons held down, so moves carry them (pointer events see a drag).
    buttons: Mutex<u32>,
}

impl Page {
    /// A CDP call on this page's session.
    pub async fn call(&self, method: &str, params: Value) -> Result<Value, CdpError> {
        self.conn
            .call(Some(&self.session_id), method, params, self.conn.timeout)
            .await
    }

    /// Runs `source` in every document this page loads from now on, before the document's own
    /// scripts (as an extension's content script would): to install what a test page needs first.
    pub async fn add_init_script(&self, source: &str) -> Result<(), CdpError> {
        self.call(
            "Page.addScriptToEvaluateOnNewDocument",
            json!({ "source": source }),
        )
        .await
        .map(drop)
    }

    /// Navigates and waits for the load event. A failed navigation (DNS, refused, aborted) is an
    /// error; an HTTP error page (404) is not: check the page or `errors()`.
    pub async fn goto(&self, url: &str) -> Result<(), CdpError> {
        let since = self.session.cursor();
        let nav = self.call("Page.navigate", json!({ "url": url })).await?;
        if let Some(error) = nav["errorText"].as_str().filter(|e| !e.is_empty()) {
            return Err(CdpError::Navigation {
                url: url.to_owned(),
                error: error.to_owned(),
            });
        }
        // No loaderId: a same-document navigation (a #fragment), with no load event.
        let Some(loader) = nav["loaderId"].as_str() else {
            return Ok(());
        };
        let frame = nav["frameId"].as_str().unwrap_or_default();
        let event = self
            .wait_event(
                since,
                self.conn.timeout,
                &format!("the load event of {url}"),
                &|e| {
                    (e.method == "Page.lifecycleEvent"
                        && e.params["name"] == "load"
                        && e.params["loaderId"] == loader
                        && e.params["frameId"] == frame)
                        || e.method == "Inspector.targetCrashed"
                },
            )
            .await?;
        if event.method == "Inspector.targetCrashed" {
            return Err(CdpError::Navigation {
                url: url.to_owned(),
                error: "the page crashed".to_owned(),
            });
        }
        Ok(())
    }

    /// Waits for an event at or after cursor `since` that `want` accepts.
    async fn wait_event(
        &self,
        since: u64,
        timeout: Duration,
        what: &str,
        want: &dyn Fn(&Event) -> bool,
    ) -> Result<Event, CdpError> {
        let deadline = tokio::time::Instant::now() + timeout;
        loop {
            // Register for wake-ups before looking, so a push in between is not missed.
            let notified = self.session.notify.notified();
            tokio::pin!(notified);
            notified.as_mut().enable();
            if let Some(e) = self.session.find(since, want) {
                return Ok(e);
            }
            if let Some(why) = self.conn.closed.lock().unwrap().clone() {
                return Err(CdpError::Closed(format!("{why} (waiting for {what})")));
            }
            if tokio::time::timeout_at(deadline, notified).await.is_err() {
                return Err(CdpError::Timeout {
                    what: what.to_owned(),
                    after: timeout,
                });
            }
        }
    }

    /// Evaluates `js` in the page (awaiting a promise) and returns its value as JSON. `undefined`
    /// is `Null`; NaN, Infinity, -0 and bigints come back as their text ("NaN"). A thrown
    /// exception is `CdpError::Js`, with its message and stack.
    pub async fn eval(&self, js: &str) -> Result<Value, CdpError> {
        self.eval_within(js, self.conn.timeout).await
    }

    async fn eval_within(&self, js: &str, timeout: Duration) -> Result<Value, CdpError> {
        Ok(self.eval_raw(js, timeout).await?.0)
    }

    /// The value as `eval` gives it, and whether JavaScript finds it truthy.
    async fn eval_raw(&self, js: &str, timeout: Duration) -> Result<(Value, bool), CdpError> {
        let params = json!({
            "expression": js,
            "awaitPromise": true,
            "returnByValue": true,
            "userGesture": true,
            // As if a person did it: pages may refuse some calls (fullscreen, audio) otherwise.
        });
        let r = self
            .conn
            .call(Some(&self.session_id), "Runtime.evaluate", params, timeout)
            .await?;
        if let Some(details) = r.get("exceptionDetails") {
            return Err(CdpError::Js {
                method: format!("Runtime.evaluate({})", clip(js, 200)),
                exception: exception_text(details),
            });
        }
        let o = &r["result"];
        Ok(match (o.get("value"), o["unserializableValue"].as_str()) {
            (Some(v), _) => (v.clone(), truthy(v)),
            (None, Some(u)) => (
                Value::String(u.to_owned()),
                !matches!(u, "NaN" | "-0" | "0n"),
            ),
            (None, None) => (Value::Null, false),
        })
    }

    /// Polls `js` (every 50 ms) until its value is truthy, and returns that value. A throwing
    /// expression counts as not yet true. On timeout the error names the expression, the last
    /// value (or exception), and the page's errors so far.
    pub async fn wait_for(&self, js: &str, timeout: Duration) -> Result<Value, CdpError> {
        let start = Instant::now();
        // The last answer the page gave, and whether a later evaluation went unanswered: a busy
        // page may answer once and then not in time, and the answer it gave is still worth naming.
        let mut last: Option<String> = None;
        let mut unanswered = false;
        loop {
            let left = timeout.saturating_sub(start.elapsed());
            if left.is_zero() {
                const UNANSWERED: &str =
                    "no answer in time (a busy page, or a promise that did not settle)";
                let was = match (&last, unanswered) {
                    (None, _) => format!("not known: {UNANSWERED}"),
                    (Some(v), false) => v.clone(),
                    (Some(v), true) => format!("{v}, then {UNANSWERED}"),
                };
                let errors = self.errors();
                let errors = if errors.is_empty() {
                    String::new()
                } else {
                    format!("; the page's errors: {errors:?}")
                };
                return Err(CdpError::Timeout {
                    what: format!("`{}` to be truthy; it was {was}{errors}", clip(js, 200)),
                    after: timeout,
                });
            }
            match self.eval_raw(js, left.min(self.conn.timeout)).await {
                Ok((v, true)) => return Ok(v),
                Ok((v, false)) => (last, unanswered) = (Some(clip(&v.to_string(), 500)), false),
                Err(CdpError::Js { exception, .. }) => {
                    (last, unanswered) =
                        (Some(format!("a throw: {}", clip(&exception, 500))), false)
                }
                Err(CdpError::Timeout { .. }) => unanswered = true,
                Err(e) => return Err(e),
            }
            tokio::time::sleep(
                Duration::from_millis(50).min(timeout.saturating_sub(start.elapsed())),
            )
            .await;
        }
    }

    /// A PNG of the viewport (its size is the page's `width`×`height`).
    pub async fn screenshot_png(&self) -> Result<Vec<u8>, CdpError> {
        let r = self
            .call("Page.captureScreenshot", json!({ "format": "png" }))
            .await?;
        let data = r["data"]
            .as_str()
            .ok_or_else(|| CdpError::Other("Page.captureScreenshot gave no data".to_owned()))?;
        base64::engine::general_purpose::STANDARD
            .decode(data)
            .map_err(|e| CdpError::Other(format!("Page.captureScreenshot: bad base64: {e}")))
    }

    /// A mouse event at (`x`, `y`) CSS pixels from the viewport's top left. Buttons stay down
    /// between `Down` and `Up`, so `Move`s in between are drags.
    pub async fn mouse(&self, kind: MouseKind, x: f64, y: f64) -> Result<(), CdpError> {
        let held = *self.buttons.lock().unwrap();
        let held_button = [MouseButton::Left, MouseButton::Right, MouseButton::Middle]
            .into_iter()
            .find(|b| held & b.bit() != 0);
        let (ty, button, buttons, clicks, dx, dy) = match kind {
            MouseKind::Move => (
                "mouseMoved",
                held_button.map_or("none", MouseButton::name),
                held,
                0,
                0.0,
                0.0,
            ),
            MouseKind::Down(b) => ("mousePressed", b.name(), held | b.bit(), 1, 0.0, 0.0),
            MouseKind::Up(b) => ("mouseReleased", b.name(), held & !b.bit(), 1, 0.0, 0.0),
            MouseKind::Wheel { dx, dy } => ("mouseWheel", "none", held, 0, dx, dy),
        };
        let params = json!({
            "type": ty, "x": x, "y": y, "button": button, "buttons": buttons,
            "clickCount": clicks, "deltaX": dx, "deltaY": dy,
        });
        self.call("Input.dispatchMouseEvent", params).await?;
        *self.buttons.lock().unwrap() = buttons;
        Ok(())
    }

    /// A press: down then up.
    pub async fn click(&self, x: f64, y: f64) -> Result<(), CdpError> {
        self.mouse(MouseKind::Move, x, y).await?;
        self.mouse(MouseKind::Down(MouseButton::Left), x, y).await?;
        self.mouse(MouseKind::Up(MouseButton::Left), x, y).await
    }

    /// A drag with `button` from `from` to `to` in `steps` moves.
    pub async fn drag(
        &self,
        button: MouseButton,
        from: (f64, f64),
        to: (f64, f64),
        steps: u32,
    ) -> Result<(), CdpError> {
        self.mouse(MouseKind::Move, from.0, from.1).await?;
        self.mouse(MouseKind::Down(button), from.0, from.1).await?;
        let steps = steps.max(1);
        for i in 1..=steps {
            let t = f64::from(i) / f64::from(steps);
            self.mouse(
                MouseKind::Move,
                from.0 + (to.0 - from.0) * t,
                from.1 + (to.1 - from.1) * t,
            )
            .await?;
        }
        self.mouse(MouseKind::Up(button), to.0, to.1).await
    }

    /// Presses and releases a key: a single character ("a", "W", "1", " "), or one of Enter,
    /// Escape, Tab, Backspace, Delete, Home, End, PageUp, PageDown, ArrowLeft/Right/Up/Down,
    /// Shift, Control, Alt.
    pub async fn key(&self, key: &str) -> Result<(), CdpError> {
        let (code, vk, text) = key_info(key).ok_or_else(|| {
            CdpError::Other(format!(
                "Page::key: no key {key:?} (single characters and named keys only)"
            ))
        })?;
        let mut down = json!({ "type": "rawKeyDown", "key": key, "code": code, "windowsVirtualKeyCode": vk, "nativeVirtualKeyCode": vk });
        if let Some(text) = &text {
            down["type"] = json!("keyDown");
            down["text"] = json!(text);
            down["unmodifiedText"] = json!(text);
        }
        self.call("Input.dispatchKeyEvent", down).await?;
        self.call("Input.dispatchKeyEvent", json!({ "type": "keyUp", "key": key, "code": code, "windowsVirtualKeyCode": vk, "nativeVirtualKeyCode": vk }))
            .await?;
        Ok(())
    }

    /// Everything the page logged so far: console calls, uncaught exceptions, and log entries
    /// (failed loads, e.g. a 404 script; security and deprecation messages).
    pub fn console(&self) -> Vec<ConsoleEntry> {
        self.session.console.lock().unwrap().clone()
    }

    /// The texts of the error-level console entries.
    pub fn errors(&self) -> Vec<String> {
        self.console()
            .into_iter()
            .filter(ConsoleEntry::is_error)
            .map(|e| e.text)
            .collect()
    }
}

impl Drop for Page {
    fn drop(&mut self) {
        self.conn.send_only(
            None,
            "Target.closeTarget",
            json!({ "targetId": self.target_id }),
        );
        self.conn.sessions.lock().unwrap().remove(&self.session_id);
    }
}

/// DOM `code`, key code, and the text a key types.
fn key_info(key: &str) -> Option<(String, u32, Option<String>)> {
    let mut chars = key.chars();
    if let (Some(c), None) = (chars.next(), chars.next()) {
        let upper = c.to_ascii_uppercase();
        return match c {
            'a'..='z' | 'A'..='Z' => {
                Some((format!("Key{upper}"), upper as u32, Some(key.to_owned())))
            }
            '0'..='9' => Some((format!("Digit{c}"), c as u32, Some(key.to_owned()))),
            ' ' => Some(("Space".to_owned(), 32, Some(" ".to_owned()))),
            _ if c.is_ascii_graphic() => Some((String::new(), 0, Some(key.to_owned()))),
            _ => None,
        };
    }
    let (vk, text) = match key {
        "Enter" => (13, Some("\r")),
        "Escape" => (27, None),
        "Tab" => (9, None),
        "Backspace" => (8, None),
        "Delete" => (46, None),
        "Home" => (36, None),
        "End" => (35, None),
        "PageUp" => (33, None),
        "PageDown" => (34, None),
        "ArrowLeft" => (37, None),
        "ArrowUp" => (38, None),
        "ArrowRight" => (39, None),
        "ArrowDown" => (40, None),
        "Shift" => (16, None),
        "Control" => (17, None),
        "Alt" => (18, None),
        _ => return None,
    };
    let code = match key {
        "Shift" | "Control" | "Alt" => format!("{key}Left"),
        _ => key.to_owned(),
    };
    Some((code, vk, text.map(str::to_owned)))
}

/// JavaScript truthiness of a returned value.
fn truthy(v: &Value) -> bool {
    match v {
        Value::Null => false,
        Value::Bool(b) => *b,
        Value::Number(n) => n.as_f64().is_some_and(|f| f != 0.0),
        Value::String(s) => !s.is_empty(),
        Value::Array(_) | Value::Object(_) => true,
    }
}

fn clip(s: &str, max: usize) -> String {
    if s.chars().count() <= max {
        s.to_owned()
    } else {
        format!("{}…", s.chars().take(max).collect::<String>())
    }
}
