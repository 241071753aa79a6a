//! `bounce bench serve`: the lighting service under load on loopback, in one process. Writers
//! change each session's lights at a fixed rate over gRPC; viewers (gRPC streams and WebSockets,
//! each on its own connection) receive frames. Per viewer and light version, the latency is from
//! the writer issuing the change to the first frame answering that version or a newer one (a
//! viewer that skips a stale frame is answered by the newer one); every frame is checked for
//! order.
//!
//! Server and clients share this machine's cores, so the figures are an upper bound on what a
//! dedicated server would show; compare rows of one run.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use bounce_engine::EngineChoice;
use bounce_server::frame::Frame;
use bounce_server::proto::{self, bounce_client::BounceClient};
use bounce_server::{Hub, HubConfig};
use clap::Args;
use futures_util::StreamExt as _;
use tokio::sync::watch;
use tonic::transport::Channel;

#[derive(Args, Debug)]
pub struct BenchServeArgs {
    /// A baked scene (.bounce).
    pub baked: PathBuf,
    /// Viewer counts, comma separated; spread evenly over the sessions.
    #[arg(long, value_delimiter = ',', default_value = "1,10,100,1000")]
    pub viewers: Vec<usize>,
    /// Session counts, comma separated (rows with fewer viewers than sessions are skipped).
    #[arg(long, value_delimiter = ',', default_value = "1,10")]
    pub sessions: Vec<usize>,
    /// Light changes per second, per session.
    #[arg(long, default_value_t = 30.0)]
    pub rate: f64,
    /// Seconds of writing per row.
    #[arg(long, default_value_t = 4.0)]
    pub seconds: f64,
    /// Share of the viewers on WebSocket; the rest use gRPC streams.
    #[arg(long, default_value_t = 0.5)]
    pub ws_share: f64,
    #[arg(long, value_name = "auto|gpu|cpu", default_value = "cpu")]
    pub engine: String,
    /// Keep sessions in memory: no durable store commit before each acknowledgement.
    #[arg(long)]
    pub memory: bool,
    /// Write the table as CSV here too.
    #[arg(long, value_name = "OUT.csv")]
    pub csv: Option<PathBuf>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
enum Via {
    Grpc,
    Ws,
}

/// What one viewer saw: per frame its arrival, lights version and sequence.
struct Seen {
    via: Via,
    session: usize,
    frames: Vec<(Instant, u64, u64)>,
}

pub fn run(args: &BenchServeArgs) -> Result<()> {
    if !(args.rate > 0.0 && args.rate.is_finite()) {
        bail!("--rate must be a positive number of changes per second");
    }
    if !(0.0..=1.0).contains(&args.ws_share) {
        bail!("--ws-share is a share between 0 and 1");
    }
    let engine: EngineChoice = args.engine.parse()?;
    let name = args
        .baked
        .file_stem()
        .and_then(|s| s.to_str())
        .context("the baked file needs a name")?
        .to_string();
    let scenes = tempfile::tempdir().context("creating a scratch directory")?;
    let baked = std::fs::canonicalize(&args.baked)
        .with_context(|| format!("reading {}", args.baked.display()))?;
    std::fs::copy(&baked, scenes.path().join(format!("{name}.bounce")))
        .with_context(|| format!("copying {}", baked.display()))?;
    let data = tempfile::tempdir().context("creating a scratch directory")?;
    let mut config = HubConfig::new(scenes.path(), engine);
    config.data_dir = (!args.memory).then(|| data.path().to_path_buf());
    config.reload_interval = None;
    config.max_connections = 100_000;
    // Every simulated viewer connects from loopback.
    config.max_connections_per_ip = 100_000;
    config.max_sessions_per_client = config.max_sessions;
    let hub = Hub::start(&config).context("starting the service")?;
    eprintln!(
        "bench serve: {name} ({} patches) on {}, {} light changes/s per session, {} s a row, {:.0}% WebSocket viewers, sessions {}",
        hub.scenes().first().map_or(0, |s| s.layout.len()),
        hub.engine(),
        args.rate,
        args.seconds,
        args.ws_share * 100.0,
        if args.memory {
            "in memory"
        } else {
            "stored (redb)"
        },
    );
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    let rows = runtime.block_on(async {
        let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
        let grpc = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
        let grpc_addr = grpc.local_addr()?;
        let http = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
        let http_addr = http.local_addr()?;
        let served = tokio::spawn(bounce_server::run(
            hub.clone(),
            bounce_server::Listeners::both(grpc, http),
            async move {
                let _ = stop_rx.await;
            },
        ));
        let mut rows = Vec::new();
        for &sessions in &args.sessions {
            for &viewers in &args.viewers {
                if sessions == 0 || viewers < sessions {
                    continue;
                }
                let before = solve_totals(&hub);
                let mut row =
                    bench_row(args, &name, grpc_addr, http_addr, sessions, viewers).await?;
                let after = solve_totals(&hub);
                let calls = after.count - before.count;
                row.push(format!(
                    "{:.2}",
                    (after.seconds - before.seconds) / calls.max(1.0) * 1e3
                ));
                row.push(format!(
                    "{:.2}",
                    (after.sets - before.sets) / calls.max(1.0)
                ));
                eprintln!("  {}", row.join("  "));
                rows.push(row);
            }
        }
        let _ = stop_tx.send(());
        let _ = served.await;
        anyhow::Ok(rows)
    })?;
    super::table::emit(&HEADER, &rows, args.csv.as_deref())?;
    if let Some(r) = rows.iter().find(|r| r[0] == "1" && r[1] == "100") {
        let p99: f64 = r[8].parse().unwrap_or(f64::INFINITY);
        println!(
            "target (1 session, 100 viewers, {} changes/s): p99 {p99:.1} ms against 25 ms: {}; out of order: {}",
            args.rate,
            if p99 < 25.0 { "met" } else { "NOT met" },
            r[12]
        );
    }
    Ok(())
}

/// Engine calls so far, from the server's own metrics: how much of the latency is solving.
#[derive(Default)]
struct SolveTotals {
    count: f64,
    seconds: f64,
    sets: f64,
}

fn solve_totals(hub: &Hub) -> SolveTotals {
    let text = hub.metrics().encode();
    let sum = |prefix: &str| -> f64 {
        text.lines()
            .filter(|l| l.starts_with(prefix))
            .filter_map(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
            .sum()
    };
    SolveTotals {
        count: sum("bounce_relight_seconds_count"),
        seconds: sum("bounce_relight_seconds_sum"),
        sets: sum("bounce_relight_batch_size_sum"),
    }
}

const HEADER: [&str; 16] = [
    "sessions",
    "viewers",
    "grpc_viewers",
    "ws_viewers",
    "changes_per_s",
    "frames_per_s",
    "latency_ms_p50",
    "latency_ms_p90",
    "latency_ms_p99",
    "latency_ms_max",
    "grpc_p99_ms",
    "ws_p99_ms",
    "out_of_order",
    "undelivered",
    "solve_ms_mean",
    "sets_per_solve",
];

async fn connect(addr: std::net::SocketAddr) -> Result<BounceClient<Channel>> {
    let channel = Channel::from_shared(format!("http://{addr}"))?
        .tcp_nodelay(true)
        .connect()
        .await
        .context("connecting to the gRPC service")?;
    Ok(BounceClient::new(channel))
}

fn light(intensity: f32) -> proto::Light {
    proto::Light {
        r#type: "point".into(),
        position: vec![0.0, 1.0, 0.0],
        color: vec![1.0, 0.95, 0.9],
        intensity: Some(intensity),
        ..Default::default()
    }
}

async fn bench_row(
    args: &BenchServeArgs,
    scene: &str,
    grpc: std::net::SocketAddr,
    http: std::net::SocketAddr,
    sessions: usize,
    viewers: usize,
) -> Result<Vec<String>> {
    let mut writer = connect(grpc).await?;
    let mut ids = Vec::with_capacity(sessions);
    for _ in 0..sessions {
        let r = writer
            .create_session(proto::CreateSessionRequest {
                scene: scene.to_string(),
                lights: vec![light(5.0)],
            })
            .await
            .context("creating a session")?
            .into_inner();
        ids.push(r.session_id);
    }
    let ids = Arc::new(ids);

    // Viewers: each on its own connection, each told to stop by `stop`.
    let (stop, stopped) = watch::channel(false);
    let (ready_tx, mut ready_rx) = tokio::sync::mpsc::channel::<()>(viewers);
    // Viewers connect in waves, as a real audience ramps up; a thousand handshakes at once on
    // loopback get connections reset.
    let opening = Arc::new(tokio::sync::Semaphore::new(CONNECTING_AT_ONCE));
    let mut tasks = Vec::with_capacity(viewers);
    for i in 0..viewers {
        let session = i % sessions;
        // Interleaved so every session gets both kinds.
        let via = if ((i / sessions) as f64 + 0.5) / (viewers / sessions).max(1) as f64
            <= args.ws_share
        {
            Via::Ws
        } else {
            Via::Grpc
        };
        let id = ids[session].clone();
        let stopped = stopped.clone();
        let ready = ready_tx.clone();
        let opening = Arc::clone(&opening);
        tasks.push(tokio::spawn(async move {
            let permit = opening.acquire_owned().await?;
            let ready = Ready {
                ready,
                permit: Some(permit),
            };
            let frames = match via {
                Via::Grpc => view_grpc(grpc, id, stopped, ready).await,
                Via::Ws => view_ws(http, id, stopped, ready).await,
            }?;
            anyhow::Ok(Seen {
                via,
                session,
                frames,
            })
        }));
    }
    drop(ready_tx);
    // Every viewer has its first frame before any change: connection setup is not latency.
    for _ in 0..viewers {
        tokio::time::timeout(Duration::from_secs(60), ready_rx.recv())
            .await
            .context("viewers did not get their first frame within a minute")?;
    }

    // Writers: one per session, one connection each, a change every 1/rate s.
    let sent: Arc<Mutex<HashMap<(usize, u64), Instant>>> = Arc::default();
    let start = Instant::now();
    let mut writers = Vec::new();
    for (s, id) in ids.iter().enumerate() {
        let mut client = connect(grpc).await?;
        let id = id.clone();
        let sent = Arc::clone(&sent);
        let period = Duration::from_secs_f64(1.0 / args.rate);
        let seconds = args.seconds;
        writers.push(tokio::spawn(async move {
            let mut tick = tokio::time::interval(period);
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            let mut version = 1u64;
            while start.elapsed().as_secs_f64() < seconds {
                tick.tick().await;
                version += 1;
                // Distinct lights every change, so each one is a new version.
                let intensity = 5.0 + (version % 97) as f32 * 0.25;
                let issued = Instant::now();
                sent.lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .insert((s, version), issued);
                let r = client
                    .set_lights(proto::SetLightsRequest {
                        session_id: id.clone(),
                        lights: vec![light(intensity)],
                        token: String::new(),
                    })
                    .await?
                    .into_inner();
                if r.lights_version != version {
                    bail!(
                        "session {s}: expected version {version}, the server said {}",
                        r.lights_version
                    );
                }
            }
            anyhow::Ok(version)
        }));
    }
    let mut last = Vec::with_capacity(sessions);
    for w in writers {
        last.push(w.await??);
    }
    let writing = start.elapsed().as_secs_f64();
    // Let the last changes arrive everywhere (bounded), then stop the viewers.
    tokio::time::sleep(Duration::from_millis(500)).await;
    let _ = stop.send(true);
    let mut seen = Vec::with_capacity(viewers);
    for t in tasks {
        seen.push(t.await??);
    }

    let sent = sent.lock().unwrap_or_else(|e| e.into_inner()).clone();
    let changes: u64 = last.iter().map(|v| v - 1).sum();
    // The first tenth of each session's versions is warm-up.
    let first_counted: Vec<u64> = last.iter().map(|&v| 2 + (v - 1) / 10).collect();
    let mut all = Vec::new();
    let mut by_via: HashMap<Via, Vec<f64>> = HashMap::new();
    let mut out_of_order = 0usize;
    let mut undelivered = 0usize;
    let mut frames = 0usize;
    for v in &seen {
        frames += v.frames.len();
        for w in v.frames.windows(2) {
            if w[1].2 <= w[0].2 || w[1].1 < w[0].1 {
                out_of_order += 1;
            }
        }
        for version in first_counted[v.session]..=last[v.session] {
            let Some(&issued) = sent.get(&(v.session, version)) else {
                continue;
            };
            match v.frames.iter().find(|f| f.1 >= version) {
                Some(f) => {
                    let ms = f.0.saturating_duration_since(issued).as_secs_f64() * 1e3;
                    all.push(ms);
                    by_via.entry(v.via).or_default().push(ms);
                }
                None => undelivered += 1,
            }
        }
    }
    let ws = seen.iter().filter(|v| v.via == Via::Ws).count();
    let q = |xs: &mut Vec<f64>, p: f64| -> String {
        if xs.is_empty() {
            return "-".into();
        }
        xs.sort_by(f64::total_cmp);
        let i = ((xs.len() - 1) as f64 * p).round() as usize;
        format!("{:.2}", xs[i])
    };
    let mut grpc_lat = by_via.remove(&Via::Grpc).unwrap_or_default();
    let mut ws_lat = by_via.remove(&Via::Ws).unwrap_or_default();
    Ok(vec![
        sessions.to_string(),
        viewers.to_string(),
        (viewers - ws).to_string(),
        ws.to_string(),
        format!("{:.1}", changes as f64 / writing),
        format!("{:.0}", frames as f64 / writing),
        q(&mut all, 0.5),
        q(&mut all, 0.9),
        q(&mut all, 0.99),
        q(&mut all, 1.0),
        q(&mut grpc_lat, 0.99),
        q(&mut ws_lat, 0.99),
        out_of_order.to_string(),
        undelivered.to_string(),
    ])
}

type Frames = Vec<(Instant, u64, u64)>;

/// Viewers opening connections at the same time.
const CONNECTING_AT_ONCE: usize = 64;

/// Told once, at a viewer's first frame: it is counted ready and frees its place in the wave.
struct Ready {
    ready: tokio::sync::mpsc::Sender<()>,
    permit: Option<tokio::sync::OwnedSemaphorePermit>,
}

impl Ready {
    async fn first_frame(&mut self) {
        if self.permit.take().is_some() {
            let _ = self.ready.send(()).await;
        }
    }
}

/// Waits for `true`; the guard `wait_for` returns is not `Send`, so it is dropped in here.
async fn until(flag: &mut watch::Receiver<bool>) {
    let _ = flag.wait_for(|&s| s).await;
}

async fn view_grpc(
    addr: std::net::SocketAddr,
    id: String,
    mut stopped: watch::Receiver<bool>,
    mut ready: Ready,
) -> Result<Frames> {
    let mut client = connect(addr).await?;
    let mut stream = client
        .subscribe(proto::SubscribeRequest { session_id: id })
        .await
        .context("subscribing")?
        .into_inner();
    let mut frames = Vec::new();
    loop {
        tokio::select! {
            _ = until(&mut stopped) => return Ok(frames),
            m = stream.message() => {
                let Some(f) = m.context("frame stream")? else { return Ok(frames) };
                frames.push((Instant::now(), f.lights_version, f.sequence));
                ready.first_frame().await;
            }
        }
    }
}

async fn view_ws(
    addr: std::net::SocketAddr,
    id: String,
    mut stopped: watch::Receiver<bool>,
    mut ready: Ready,
) -> Result<Frames> {
    use tokio_tungstenite::tungstenite::Message;
    let url = format!("ws://{addr}/v1/sessions/{id}/ws");
    let (mut socket, _) = tokio_tungstenite::connect_async(&url)
        .await
        .with_context(|| format!("opening {url}"))?;
    let mut frames = Vec::new();
    loop {
        tokio::select! {
            _ = until(&mut stopped) => {
                let _ = socket.close(None).await;
                return Ok(frames);
            }
            m = socket.next() => {
                let Some(m) = m else { return Ok(frames) };
                match m.context("WebSocket")? {
                    Message::Binary(bytes) => {
                        let f = Frame::parse(bytes).context("a frame")?;
                        frames.push((Instant::now(), f.header.lights_version, f.header.sequence));
                        ready.first_frame().await;
                    }
                    Message::Close(_) => return Ok(frames),
                    _ => {}
                }
            }
        }
    }
}
