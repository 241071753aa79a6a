//! `bounce serve`: the lighting service on gRPC and HTTP/WebSocket, with the embedded demo when no
//! scenes are given.
//!
//! This is the binary's edge: flags and environment, logging, the tokio runtime, signals. The
//! service itself is `bounce-server`.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result};
use bounce_core::format::Baked;
use bounce_engine::EngineChoice;
use bounce_server::{Hub, HubConfig};
use clap::Args;
use tracing::{info, warn};

#[derive(Args, Debug)]
pub struct ServeArgs {
    /// Directory of baked scenes: every `NAME.bounce` in it is served as scene NAME. Without it,
    /// the embedded Cornell box demo, baked into the cache directory on first start.
    #[arg(long, value_name = "DIR", env = "BOUNCE_SCENES")]
    pub scenes: Option<PathBuf>,
    /// Address of the gRPC service (with health and reflection, so `grpcurl` works).
    #[arg(
        long,
        value_name = "ADDR",
        default_value = "127.0.0.1:50051",
        env = "BOUNCE_GRPC"
    )]
    pub grpc: SocketAddr,
    /// Address of the HTTP front end: health, readiness, metrics, scenes, sessions and each
    /// session's WebSocket.
    #[arg(
        long,
        value_name = "ADDR",
        default_value = "127.0.0.1:8080",
        env = "BOUNCE_HTTP"
    )]
    pub http: SocketAddr,
    /// `auto` takes the GPU when a hardware adapter exists, else the CPU, and says which.
    #[arg(
        long,
        value_name = "auto|gpu|cpu",
        default_value = "auto",
        env = "BOUNCE_ENGINE"
    )]
    pub engine: String,
    /// Where the demo scene is baked [default: $XDG_CACHE_HOME/bounce, else ~/.cache/bounce].
    #[arg(long, value_name = "DIR", env = "BOUNCE_CACHE_DIR")]
    pub cache_dir: Option<PathBuf>,
    /// Where sessions are stored so they survive restarts and crashes
    /// [default: $XDG_DATA_HOME/bounce, else ~/.local/share/bounce].
    #[arg(
        long,
        value_name = "DIR",
        env = "BOUNCE_DATA_DIR",
        conflicts_with = "memory"
    )]
    pub data_dir: Option<PathBuf>,
    /// Keep sessions in memory only: they end with the process.
    #[arg(long)]
    pub memory: bool,
    /// A session nobody watches or writes for this long is removed (`90s`, `30m`, `24h`).
    #[arg(long, value_name = "DURATION", default_value = "24h", value_parser = parse_duration, env = "BOUNCE_SESSION_TTL")]
    pub session_ttl: Duration,
    /// How often the scene directory is checked for new or changed baked files (`0` never).
    #[arg(long, value_name = "DURATION", default_value = "2s", value_parser = parse_duration, env = "BOUNCE_RELOAD_EVERY")]
    pub reload_every: Duration,
    /// Writes (creating sessions, changing lights, one-shot relights) must present this token:
    /// `authorization: Bearer T` (gRPC metadata or HTTP header) or, over HTTP, `?token=T`.
    /// Viewing needs none unless --read-token is set.
    #[arg(long, value_name = "T", env = "BOUNCE_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// Reads of scenes and sessions (listing, layouts, models, frame streams, over gRPC, HTTP
    /// and WebSocket) must present this token or the write token. Health, readiness, metrics
    /// and the page's files stay open; open the page with `?token=T`.
    #[arg(
        long,
        value_name = "T",
        env = "BOUNCE_READ_TOKEN",
        hide_env_values = true
    )]
    pub read_token: Option<String>,
    /// Serve the browser page from this directory (e.g. web/public), read again on every
    /// request, instead of the copy built into the binary: for working on the page.
    #[arg(long, value_name = "DIR", env = "BOUNCE_WEB_DIR")]
    pub web_dir: Option<PathBuf>,
    /// Open connections each front end accepts; past it a new connection is closed at once.
    #[arg(
        long,
        value_name = "N",
        default_value_t = 4096,
        env = "BOUNCE_MAX_CONNECTIONS"
    )]
    pub max_connections: usize,
    /// Open connections each front end accepts from one IP address (so that one client cannot
    /// take every place; raise it for many clients behind one NAT or proxy).
    #[arg(
        long,
        value_name = "N",
        default_value_t = 256,
        env = "BOUNCE_MAX_CONNECTIONS_PER_IP"
    )]
    pub max_connections_per_ip: usize,
    /// Sessions held at most; creating one more is refused (429 / RESOURCE_EXHAUSTED) until
    /// idle ones expire.
    #[arg(
        long,
        value_name = "N",
        default_value_t = 10_000,
        env = "BOUNCE_MAX_SESSIONS"
    )]
    pub max_sessions: usize,
    /// Sessions one client address may hold at most (so that one client cannot take every
    /// place of --max-sessions; raise it for many clients behind one NAT or proxy); creating
    /// one more is refused (429 / RESOURCE_EXHAUSTED) until its idle ones expire.
    #[arg(
        long,
        value_name = "N",
        default_value_t = 64,
        env = "BOUNCE_MAX_SESSIONS_PER_CLIENT"
    )]
    pub max_sessions_per_client: usize,
    /// A WebSocket client silent this long is pinged, and closed (1008) when nothing comes back
    /// within as long again, or when a frame cannot be handed to it within it: a dead or stalled
    /// peer. Browsers and WebSocket libraries answer pings by themselves.
    #[arg(long, value_name = "DURATION", default_value = "30s", value_parser = parse_duration, env = "BOUNCE_WS_KEEPALIVE")]
    pub ws_keepalive: Duration,
    /// A web origin besides the server's own (`https://app.example.com`) whose pages may create
    /// sessions and change lights; repeat for more. Requests without an Origin (gRPC, scripts)
    /// are not affected.
    #[arg(
        long = "allow-origin",
        value_name = "ORIGIN",
        env = "BOUNCE_ALLOW_ORIGIN",
        value_delimiter = ','
    )]
    pub allow_origins: Vec<String>,
}

/// `250ms`, `90s`, `30m`, `24h`, or plain seconds.
fn parse_duration(s: &str) -> Result<Duration, String> {
    let s = s.trim();
    let split = s
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(s.len());
    let (number, unit) = s.split_at(split);
    let n: f64 = number
        .parse()
        .map_err(|_| format!("{s:?} is not a duration like 250ms, 90s, 30m or 24h"))?;
    let seconds = match unit {
        "" | "s" => n,
        "ms" => n / 1e3,
        "m" => n * 60.0,
        "h" => n * 3600.0,
        "d" => n * 86400.0,
        _ => return Err(format!("{unit:?}: the unit is one of ms, s, m, h, d")),
    };
    Duration::try_from_secs_f64(seconds).map_err(|e| format!("{s:?}: {e}"))
}

pub fn run(args: &ServeArgs) -> Result<()> {
    init_logging();
    let engine: EngineChoice = args.engine.parse()?;
    let scenes_dir = match &args.scenes {
        Some(dir) => dir.clone(),
        None => demo_scenes(args.cache_dir.clone())?,
    };
    let data_dir = if args.memory {
        None
    } else {
        Some(args.data_dir.clone().unwrap_or_else(default_data_dir))
    };
    let mut config = HubConfig::new(&scenes_dir, engine);
    config.data_dir = data_dir.clone();
    config.session_ttl = args.session_ttl;
    config.token = args.token.clone();
    config.read_token = args.read_token.clone();
    if let Some(dir) = &args.web_dir
        && !dir.join("index.html").is_file()
    {
        anyhow::bail!(
            "--web-dir {}: no index.html there (give the page's directory, e.g. web/public)",
            dir.display()
        );
    }
    config.web_dir = args.web_dir.clone();
    config.max_connections = args.max_connections;
    config.max_connections_per_ip = args.max_connections_per_ip;
    config.max_sessions = args.max_sessions;
    config.max_sessions_per_client = args.max_sessions_per_client;
    anyhow::ensure!(
        !args.ws_keepalive.is_zero(),
        "--ws-keepalive must be longer than 0: it is how long a silent client has to answer a ping"
    );
    config.ws_keepalive = args.ws_keepalive;
    config.allowed_origins = args.allow_origins.clone();
    config.reload_interval = (!args.reload_every.is_zero()).then_some(args.reload_every);
    // Blocking (reads files, may upload to a GPU): before the runtime serves.
    let hub = Hub::start(&config)
        .with_context(|| format!("starting the service on {}", scenes_dir.display()))?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .thread_name("bounce-serve")
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(async {
        let grpc_listener = tokio::net::TcpListener::bind(args.grpc)
            .await
            .with_context(|| format!("binding the gRPC address {}", args.grpc))?;
        let http_listener = tokio::net::TcpListener::bind(args.http)
            .await
            .with_context(|| format!("binding the HTTP address {}", args.http))?;
        // The bound addresses, not the flags: port 0 prints the port it got.
        let grpc = grpc_listener
            .local_addr()
            .context("reading the bound address")?;
        let http = http_listener
            .local_addr()
            .context("reading the bound address")?;
        let names: Vec<String> = hub.scenes().iter().map(|s| s.name.clone()).collect();
        let sessions = match &data_dir {
            Some(d) => format!("sessions stored in {}", d.display()),
            None => "sessions in memory only".to_string(),
        };
        let banner = [
            format!("bounce: serving {} on {}", names.join(", "), hub.engine()),
            format!("  {sessions}"),
            format!("  gRPC  http://{grpc}   (try: grpcurl -plaintext {grpc} list)"),
            format!(
                "  HTTP  http://{http}   (health /healthz, metrics /metrics, scenes /v1/scenes)"
            ),
            format!(
                "  page  http://{http}/{}   ({})",
                // With one scene, the URL that opens it: the first thing a newcomer wants.
                match names.as_slice() {
                    [one] => format!("?scene={}", query_escape(one)),
                    _ => String::new(),
                },
                match &args.web_dir {
                    Some(d) => format!("from {}", d.display()),
                    None => "built in".to_string(),
                }
            ),
            format!("  WebSocket  ws://{http}/v1/sessions/SESSION_ID/ws"),
            String::new(),
        ]
        .join("\n");
        // One write, and its failure ignored: a reader that stops after the line it wanted (or
        // a closed stdout) must not kill the server, as `println!` would.
        {
            use std::io::Write as _;
            let mut out = std::io::stdout().lock();
            let _ = out.write_all(banner.as_bytes()).and_then(|()| out.flush());
        }
        info!(%grpc, %http, "listening");
        // Loopback is the default; an address others can reach without a token is a choice
        // the operator should see made.
        let exposed: Vec<String> = [grpc, http]
            .iter()
            .filter(|a| !a.ip().is_loopback())
            .map(ToString::to_string)
            .collect();
        if !exposed.is_empty() && !hub.has_token() {
            warn!(
                addresses = %exposed.join(", "),
                "reachable beyond this machine with no write token: anyone who reaches it can \
                 create sessions and change lights (set --token)"
            );
        }
        if !exposed.is_empty() && !hub.has_read_token() {
            warn!(
                addresses = %exposed.join(", "),
                "reachable beyond this machine with no read token: anyone who reaches it can \
                 list the sessions and watch their light (set --read-token)"
            );
        }

        // Both front ends stop on the signal, or when either ends on an error.
        bounce_server::run(
            hub,
            bounce_server::Listeners::both(grpc_listener, http_listener),
            shutdown_signal(),
        )
        .await
        .context("serving")
    })?;
    info!("stopped");
    Ok(())
}

/// `s` percent-encoded for a URL's query: a scene is named after its file, which may hold
/// anything. RFC 3986's unreserved characters stay as they are.
fn query_escape(s: &str) -> String {
    s.bytes()
        .map(|b| match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'.' | b'_' | b'~' => {
                char::from(b).to_string()
            }
            _ => format!("%{b:02X}"),
        })
        .collect()
}

/// Logs to stderr; `RUST_LOG` takes `tracing` target filters (`info`, `bounce_server=debug`).
fn init_logging() {
    use std::io::IsTerminal;
    use tracing_subscriber::filter::Targets;
    use tracing_subscriber::prelude::*;
    let filter = std::env::var("RUST_LOG")
        .ok()
        .and_then(|s| s.parse::<Targets>().ok())
        .unwrap_or_else(|| Targets::new().with_default(tracing::Level::INFO));
    let _ = tracing_subscriber::registry()
        .with(
            tracing_subscriber::fmt::layer()
                .with_writer(std::io::stderr)
                .with_ansi(std::io::stderr().is_terminal()),
        )
        .with(filter)
        .try_init();
}

/// Ctrl-C or SIGTERM.
async fn shutdown_signal() {
    let ctrl_c = async {
        if tokio::signal::ctrl_c().await.is_err() {
            std::future::pending::<()>().await;
        }
    };
    #[cfg(unix)]
    let term = async {
        use tokio::signal::unix::{SignalKind, signal};
        match signal(SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {}
        _ = term => {}
    }
}

fn default_data_dir() -> PathBuf {
    std::env::var_os("XDG_DATA_HOME")
        .map(|d| PathBuf::from(d).join("bounce"))
        .or_else(|| std::env::var_os("HOME").map(|d| PathBuf::from(d).join(".local/share/bounce")))
        .unwrap_or_else(|| std::env::temp_dir().join("bounce-data"))
}

/// The demo's scene directory, baking the embedded Cornell box there unless a readable baked
/// file is already in it.
fn demo_scenes(cache_dir: Option<PathBuf>) -> Result<PathBuf> {
    let cache = cache_dir
        .or_else(|| std::env::var_os("XDG_CACHE_HOME").map(|d| PathBuf::from(d).join("bounce")))
        .or_else(|| std::env::var_os("HOME").map(|d| PathBuf::from(d).join(".cache/bounce")))
        .unwrap_or_else(|| std::env::temp_dir().join("bounce-cache"));
    let demo = cache.join("demo");
    let scenes = demo.join("scenes");
    let baked = scenes.join("cornell-box.bounce");
    let bake = crate::demo::DemoBake::default();
    // A cached bake from a bounce that did not keep the model is baked again: the page needs it.
    // So is one made with another codec request (an older bounce's exact dense-f32): the demo
    // serves what a bake gives by default.
    let cached = Baked::read(&baked)
        .map_err(|e| e.to_string())
        .and_then(|b| {
            let asked = bounce_core::bake::options_of(&b.meta.settings, false).codec;
            if b.model.is_none() {
                Err("it has no model for the browser page".to_string())
            } else if asked != bake.codec {
                Err(format!(
                    "it was baked with codec {}, the demo now asks for {}",
                    crate::bake::codec_request_label(&asked),
                    crate::bake::codec_request_label(&bake.codec)
                ))
            } else {
                Ok(())
            }
        });
    match cached {
        Ok(()) => info!(file = %baked.display(), "demo scene from the cache"),
        Err(e) => {
            if baked.exists() {
                info!(file = %baked.display(), error = %e, "cached demo not usable, baking again");
            }
            std::fs::create_dir_all(&scenes)
                .with_context(|| format!("creating {}", scenes.display()))?;
            eprintln!(
                "bounce: baking the demo Cornell box into {} (first start only)",
                demo.display()
            );
            crate::demo::bake_demo(&demo, &baked, &bake, false)?;
        }
    }
    Ok(scenes)
}

#[cfg(test)]
mod tests {
    use super::{parse_duration, query_escape};
    use std::time::Duration;

    #[test]
    fn scene_names_are_escaped_for_the_page_url() {
        assert_eq!(query_escape("cornell-box"), "cornell-box");
        assert_eq!(query_escape("my level #2"), "my%20level%20%232");
        assert_eq!(query_escape("é"), "%C3%A9");
    }

    #[test]
    fn durations_read_with_their_units() {
        assert_eq!(parse_duration("250ms"), Ok(Duration::from_millis(250)));
        assert_eq!(parse_duration("90"), Ok(Duration::from_secs(90)));
        assert_eq!(parse_duration("30m"), Ok(Duration::from_secs(1800)));
        assert_eq!(parse_duration("24h"), Ok(Duration::from_secs(86400)));
        assert_eq!(parse_duration("0"), Ok(Duration::ZERO));
        assert!(parse_duration("soon").is_err());
        assert!(parse_duration("5 parsecs").is_err());
        assert!(parse_duration("-1s").is_err());
    }
}
