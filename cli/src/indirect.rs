//! Where indirect light comes from, for `bounce view` and `bounce render` alike: a session on a
//! running server, watched as any viewer watches it, or a baked file relit in this process.
//!
//! Both take light changes without blocking the window (`send`) and hand back the newest
//! answer (`poll`); a change is tagged so the window can time it from the key press to the
//! frame that shows it. A one-off image waits for the first answer ([`Source::first_answer`]).

use std::path::Path;
use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use bounce_client::{
    Client, ClientConfig, ConnectionState, Frame, Layout, LightSet, Volume, Watcher,
};
use bounce_core::format::Baked;
use bounce_engine::{Engine, EngineChoice};
use bounce_render::layout_from_baked;
use tokio::sync::{mpsc as tmpsc, watch};

/// What a poll brought.
pub struct Answer {
    /// The lights version it answers: a tag from `send` for in-process light, the server's
    /// version for a session.
    pub lights_version: u64,
    /// The frame sequence (per server run), or the in-process solve count.
    pub sequence: u64,
    /// Irradiance at the layout's probes (`6 · probe + direction`), when the scene has them.
    pub probes: Option<Vec<[f32; 3]>>,
}

/// A change `send` was given, answered with the lights version it got.
pub struct Ack {
    pub tag: u64,
    pub lights_version: Option<u64>,
    /// Why a write was refused (a read-only viewer, a bad light).
    pub error: Option<String>,
}

pub enum Source {
    Remote(Box<Remote>),
    Local(Local),
}

impl Source {
    pub fn layout(&self) -> &Layout {
        match self {
            Source::Remote(r) => &r.layout,
            Source::Local(l) => &l.layout,
        }
    }

    /// Asks for `lights` to be solved; the answer comes through `poll` and `acks`.
    pub fn send(&mut self, tag: u64, lights: &LightSet) {
        match self {
            Source::Remote(r) => {
                // The writer task only ends with the source.
                let _ = r.writes.send((tag, lights.clone()));
            }
            Source::Local(l) => {
                let _ = l.requests.send((tag, lights.clone()));
            }
        }
    }

    /// Writes answered since the last call.
    pub fn acks(&mut self) -> Vec<Ack> {
        match self {
            Source::Remote(r) => {
                let acks: Vec<Ack> = r.acks.try_iter().collect();
                for v in acks.iter().filter_map(|a| a.lights_version) {
                    r.known = r.known.max(v);
                }
                acks
            }
            // In-process, the tag is the version.
            Source::Local(_) => Vec::new(),
        }
    }

    /// Applies the newest answer not yet applied to `volume`.
    pub fn poll(&mut self, volume: &mut Volume) -> Result<Option<Answer>> {
        match self {
            Source::Remote(r) => {
                if !r.frames.has_changed().unwrap_or(false) {
                    return Ok(None);
                }
                let frame: Option<Frame> = r.frames.borrow_and_update().clone();
                let Some(frame) = frame else { return Ok(None) };
                let version = frame.header.lights_version;
                if version > r.known {
                    // Someone else changed the lights: read them, for direct light.
                    r.known = version;
                    let (client, id, tx) =
                        (r.client.clone(), r.session.clone(), r.lights_tx.clone());
                    r.runtime.spawn(async move {
                        if let Ok(s) = client.get_session(&id).await {
                            let _ = tx.send((s.lights_version, s.lights));
                        }
                    });
                }
                volume
                    .apply(&frame)
                    .context("a frame does not fit the scene's layout")?;
                Ok(Some(Answer {
                    lights_version: frame.header.lights_version,
                    sequence: frame.header.sequence,
                    probes: frame.probes().map(|p| p.irradiance()),
                }))
            }
            Source::Local(l) => {
                let mut newest = None;
                for result in l.results.try_iter() {
                    newest = Some(result);
                }
                match newest {
                    None => Ok(None),
                    Some(Err(e)) => bail!("relighting in process: {e}"),
                    Some(Ok((tag, indirect, probes))) => {
                        l.solves += 1;
                        volume.apply_irradiance(&indirect)?;
                        Ok(Some(Answer {
                            lights_version: tag,
                            sequence: l.solves,
                            probes: (!probes.is_empty()).then_some(probes),
                        }))
                    }
                }
            }
        }
    }

    /// Waits up to `patience` for the first answer and applies it to `volume`.
    pub fn first_answer(&mut self, volume: &mut Volume, patience: Duration) -> Result<Answer> {
        let deadline = Instant::now() + patience;
        loop {
            if let Some(answer) = self.poll(volume)? {
                return Ok(answer);
            }
            if Instant::now() >= deadline {
                bail!(
                    "no indirect light within {:.0} s from {}",
                    patience.as_secs_f64(),
                    self.status()
                );
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// Lights another writer set, with their version, newest last.
    pub fn others_lights(&mut self) -> Option<(u64, LightSet)> {
        match self {
            Source::Remote(r) => r.lights_rx.try_iter().last(),
            Source::Local(_) => None,
        }
    }

    /// One line for the overlay.
    pub fn status(&self) -> String {
        match self {
            Source::Remote(r) => {
                let state = match &*r.state.borrow() {
                    ConnectionState::Connecting { attempt } => format!("connecting ({attempt})"),
                    ConnectionState::Live { .. } => "live".into(),
                    ConnectionState::Disconnected {
                        retry_in, error, ..
                    } => format!(
                        "disconnected, retry in {:.1} s: {}",
                        retry_in.as_secs_f32(),
                        error.chars().take(60).collect::<String>()
                    ),
                };
                format!("{} session {} ({state})", r.url, short(&r.session))
            }
            Source::Local(l) => format!("in process: {}", l.describe()),
        }
    }
}

fn short(id: &str) -> &str {
    id.get(..8).unwrap_or(id)
}

/// A session on a server: a watcher for frames, a writer task for light changes.
pub struct Remote {
    pub url: String,
    pub session: String,
    layout: Layout,
    frames: watch::Receiver<Option<Frame>>,
    state: watch::Receiver<ConnectionState>,
    writes: tmpsc::UnboundedSender<(u64, LightSet)>,
    acks: mpsc::Receiver<Ack>,
    client: Client,
    /// The newest lights version this viewer wrote or read.
    known: u64,
    lights_tx: mpsc::Sender<(u64, LightSet)>,
    lights_rx: mpsc::Receiver<(u64, LightSet)>,
    // Dropping the watcher stops it.
    _watcher: Watcher,
    runtime: tokio::runtime::Runtime,
}

impl Remote {
    /// Connects, fetches the layout, and joins `session` or creates one with `lights`.
    pub fn connect(
        url: &str,
        token: Option<&str>,
        scene: &str,
        session: Option<&str>,
        lights: &LightSet,
    ) -> Result<(Remote, Option<LightSet>)> {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("bounce-view-net")
            .enable_all()
            .build()
            .context("starting the async runtime")?;
        let mut config = ClientConfig::new(url);
        if let Some(t) = token {
            config = config.with_token(t);
        }
        let (client, layout, id, session_lights, known) = runtime.block_on(async {
            let client = Client::connect(config.clone())
                .await
                .with_context(|| format!("connecting to {url}"))?;
            let layout = client
                .get_layout(scene)
                .await
                .with_context(|| format!("fetching the layout of {scene:?}"))?;
            let (id, session_lights, known) = match session {
                Some(id) => {
                    let s = client
                        .get_session(id)
                        .await
                        .with_context(|| format!("looking up session {id}"))?;
                    if s.scene != scene {
                        bail!("session {id} is on scene {:?}, not {scene:?}", s.scene);
                    }
                    (id.to_string(), Some(s.lights), s.lights_version)
                }
                None => {
                    let created = client
                        .create_session(scene, lights)
                        .await
                        .context("creating a session")?;
                    (created.id, None, created.lights_version)
                }
            };
            anyhow::Ok((client, layout, id, session_lights, known))
        })?;
        let watcher = {
            let _inside = runtime.enter();
            Watcher::spawn(config, id.clone())
        };
        let (writes, rx) = tmpsc::unbounded_channel();
        let (ack_tx, acks) = mpsc::channel();
        runtime.spawn(writer(client.clone(), id.clone(), rx, ack_tx));
        let (lights_tx, lights_rx) = mpsc::channel();
        Ok((
            Remote {
                url: url.to_string(),
                session: id,
                layout,
                frames: watcher.frames(),
                state: watcher.state(),
                writes,
                acks,
                client,
                known,
                lights_tx,
                lights_rx,
                _watcher: watcher,
                runtime,
            },
            session_lights,
        ))
    }
}

/// One write at a time, in order, always the newest waiting: a burst of key presses becomes
/// one `SetLights` per round trip, and the session never ends on an older configuration.
async fn writer(
    client: Client,
    session: String,
    mut rx: tmpsc::UnboundedReceiver<(u64, LightSet)>,
    acks: mpsc::Sender<Ack>,
) {
    while let Some(first) = rx.recv().await {
        let mut tags = vec![first.0];
        let mut lights = first.1;
        while let Ok((tag, newer)) = rx.try_recv() {
            tags.push(tag);
            lights = newer;
        }
        let answer = client.set_lights(&session, &lights).await;
        for tag in tags {
            let ack = match &answer {
                Ok(change) => Ack {
                    tag,
                    lights_version: Some(change.lights_version),
                    error: None,
                },
                Err(e) => Ack {
                    tag,
                    lights_version: None,
                    error: Some(e.to_string()),
                },
            };
            if acks.send(ack).is_err() {
                return;
            }
        }
    }
}

/// A tagged light change's indirect irradiance per patch and irradiance per probe direction,
/// or why it could not be solved.
type Solved = Result<(u64, Vec<[f32; 3]>, Vec<[f32; 3]>), String>;

/// A baked file relit by an engine on a thread of its own.
pub struct Local {
    layout: Layout,
    requests: mpsc::Sender<(u64, LightSet)>,
    results: mpsc::Receiver<Solved>,
    describe: std::sync::Arc<std::sync::Mutex<String>>,
    solves: u64,
    _worker: JoinHandle<()>,
}

impl Local {
    pub fn open(path: &Path, choice: EngineChoice) -> Result<Local> {
        let baked = Baked::read(path).with_context(|| format!("reading {}", path.display()))?;
        let name = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let probes: Vec<f32> = baked
            .probes
            .iter()
            .flat_map(|p| p.positions.iter().flatten().copied())
            .collect();
        let layout = layout_from_baked(&name, &baked.layout)?.with_probes(&probes)?;
        let (requests, rx) = mpsc::channel::<(u64, LightSet)>();
        let (tx, results) = mpsc::channel();
        let describe = std::sync::Arc::new(std::sync::Mutex::new("loading".to_string()));
        let shown = describe.clone();
        let worker = std::thread::Builder::new()
            .name("bounce-view-relight".into())
            .spawn(move || {
                let loaded = Engine::new(choice).and_then(|engine| {
                    let loaded = engine.load(&baked)?;
                    Ok((engine, loaded))
                });
                let (engine, loaded) = match loaded {
                    Ok(v) => v,
                    Err(e) => {
                        let _ = tx.send(Err(e.to_string()));
                        return;
                    }
                };
                if let Ok(mut d) = shown.lock() {
                    *d = engine.describe().to_string();
                }
                drop(baked);
                while let Ok(mut request) = rx.recv() {
                    // Only the newest waiting change is worth solving.
                    while let Ok(newer) = rx.try_recv() {
                        request = newer;
                    }
                    let (tag, lights) = request;
                    let answer = engine
                        .relight(&loaded, std::slice::from_ref(&lights))
                        .map_err(|e| e.to_string())
                        .and_then(|lit| {
                            lit.into_iter()
                                .next()
                                .map(|l| (tag, l.streamed().into_owned(), l.probes))
                                .ok_or_else(|| "the engine answered no light set".to_string())
                        });
                    if tx.send(answer).is_err() {
                        return;
                    }
                }
            })
            .context("starting the relight thread")?;
        Ok(Local {
            layout,
            requests,
            results,
            describe,
            solves: 0,
            _worker: worker,
        })
    }

    fn describe(&self) -> String {
        self.describe
            .lock()
            .map(|d| d.clone())
            .unwrap_or_else(|p| p.into_inner().clone())
    }
}
