//! The session store: every session's scene, lights and version in an embedded database
//! (`redb`) in the server's data directory, so sessions survive a restart or a crash.
//!
//! A change is committed (fsync'd) before the caller acknowledges it. Commits are grouped: one
//! thread takes every write waiting when it is free and commits them in one transaction, so a
//! burst of light changes across many sessions costs one fsync, not one each.

use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::Instant;

use bounce_core::light::LightSet;
use redb::{Database, ReadableDatabase, ReadableTable, TableDefinition};
use serde::{Deserialize, Serialize};
use thiserror::Error;
use tokio::sync::oneshot;
use tracing::{error, warn};

use crate::metrics::Metrics;

/// Session id → JSON [`StoredSession`].
const SESSIONS: TableDefinition<&str, &[u8]> = TableDefinition::new("sessions");
/// Records this server could not read, moved out of `sessions` at open so they are not read
/// (and logged) on every start, but kept: a newer server may read them, an operator may look.
const UNREADABLE: TableDefinition<&str, &[u8]> = TableDefinition::new("sessions_unreadable");

/// The file name inside the data directory.
pub const FILE_NAME: &str = "sessions.redb";

#[derive(Debug, Error)]
pub enum StoreError {
    #[error("session store {path}: {source}")]
    Open { path: PathBuf, source: redb::Error },
    #[error("session store: {0}")]
    Db(#[from] redb::Error),
    /// A commit failed; every write of its group gets the message.
    #[error("session store commit: {0}")]
    Commit(String),
    #[error("session store: the writer thread has stopped")]
    Gone,
}

/// What is kept of a session. JSON, so a newer server can add fields and an operator can read
/// it with any redb tool.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StoredSession {
    pub scene: String,
    pub lights: LightSet,
    pub version: u64,
    /// When the session was last written (milliseconds since the Unix epoch), so that its idle
    /// time, and so its expiry, survive a restart. Absent in records of older servers.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub written_unix_ms: Option<u64>,
}

/// Now, in milliseconds since the Unix epoch (0 on a clock set before it).
pub fn unix_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

enum Op {
    Put(String, Vec<u8>),
    Delete(String),
}

struct Write {
    op: Op,
    done: oneshot::Sender<Result<(), StoreError>>,
}

pub struct Store {
    writes: Option<mpsc::Sender<Write>>,
    thread: Option<JoinHandle<()>>,
}

impl Store {
    /// Opens (or creates) the store in `dir` and returns every session it holds. Records that
    /// do not parse are logged and skipped, never fatal.
    pub fn open(
        dir: &Path,
        metrics: std::sync::Arc<Metrics>,
    ) -> Result<(Store, Vec<(String, StoredSession)>), StoreError> {
        let path = dir.join(FILE_NAME);
        let open_err = |source: redb::Error| StoreError::Open {
            path: path.clone(),
            source,
        };
        std::fs::create_dir_all(dir).map_err(|e| open_err(e.into()))?;
        let db = Database::create(&path).map_err(|e| open_err(e.into()))?;
        // Create the table once so readers never meet a missing one.
        let txn = db.begin_write().map_err(|e| open_err(e.into()))?;
        txn.open_table(SESSIONS).map_err(|e| open_err(e.into()))?;
        txn.commit().map_err(|e| open_err(e.into()))?;

        let mut sessions = Vec::new();
        let mut unreadable = Vec::new();
        let read = db.begin_read().map_err(|e| open_err(e.into()))?;
        let table = read.open_table(SESSIONS).map_err(|e| open_err(e.into()))?;
        for entry in table.iter().map_err(|e| open_err(e.into()))? {
            let (k, v) = entry.map_err(|e| open_err(e.into()))?;
            let id = k.value().to_string();
            match serde_json::from_slice::<StoredSession>(v.value()) {
                Ok(s) => sessions.push((id, s)),
                Err(e) => {
                    warn!(session = %id, error = %e, "unreadable stored session moved to the sessions_unreadable table");
                    unreadable.push((id, v.value().to_vec()));
                }
            }
        }
        drop(table);
        drop(read);
        if !unreadable.is_empty() {
            let txn = db.begin_write().map_err(|e| open_err(e.into()))?;
            {
                let mut from = txn.open_table(SESSIONS).map_err(|e| open_err(e.into()))?;
                let mut to = txn.open_table(UNREADABLE).map_err(|e| open_err(e.into()))?;
                for (id, bytes) in &unreadable {
                    to.insert(id.as_str(), bytes.as_slice())
                        .map_err(|e| open_err(e.into()))?;
                    from.remove(id.as_str()).map_err(|e| open_err(e.into()))?;
                }
            }
            txn.commit().map_err(|e| open_err(e.into()))?;
        }

        let (tx, rx) = mpsc::channel::<Write>();
        let thread = std::thread::Builder::new()
            .name("bounce-store".into())
            .spawn(move || write_loop(&db, &rx, &metrics))
            .map_err(|e| open_err(e.into()))?;
        Ok((
            Store {
                writes: Some(tx),
                thread: Some(thread),
            },
            sessions,
        ))
    }

    /// Durably records `session` under `id`; resolves once committed.
    pub async fn put(&self, id: &str, session: &StoredSession) -> Result<(), StoreError> {
        // Serialising plain data with string keys cannot fail.
        let bytes = serde_json::to_vec(session).unwrap_or_default();
        self.submit(Op::Put(id.to_string(), bytes))?
            .await
            .map_err(|_| StoreError::Gone)?
    }

    /// Removes `id`; for the expiry thread, which may block.
    pub fn delete_blocking(&self, id: &str) -> Result<(), StoreError> {
        self.submit(Op::Delete(id.to_string()))?
            .blocking_recv()
            .map_err(|_| StoreError::Gone)?
    }

    fn submit(&self, op: Op) -> Result<oneshot::Receiver<Result<(), StoreError>>, StoreError> {
        let (done, rx) = oneshot::channel();
        self.writes
            .as_ref()
            .ok_or(StoreError::Gone)?
            .send(Write { op, done })
            .map_err(|_| StoreError::Gone)?;
        Ok(rx)
    }
}

impl Drop for Store {
    fn drop(&mut self) {
        // Closing the channel ends the writer after what it has; wait so the file is closed.
        self.writes = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn write_loop(db: &Database, rx: &mpsc::Receiver<Write>, metrics: &Metrics) {
    while let Ok(first) = rx.recv() {
        let mut batch = vec![first];
        batch.extend(rx.try_iter());
        let start = Instant::now();
        let result = commit(db, &batch);
        metrics
            .store_commit_seconds
            .observe(start.elapsed().as_secs_f64());
        if let Err(e) = &result {
            error!(error = %e, writes = batch.len(), "session store commit failed");
        }
        for w in batch {
            let _ = w.done.send(match &result {
                Ok(()) => Ok(()),
                Err(e) => Err(StoreError::Commit(e.to_string())),
            });
        }
    }
}

fn commit(db: &Database, batch: &[Write]) -> Result<(), redb::Error> {
    let txn = db.begin_write()?;
    {
        let mut table = txn.open_table(SESSIONS)?;
        for w in batch {
            match &w.op {
                Op::Put(id, bytes) => {
                    table.insert(id.as_str(), bytes.as_slice())?;
                }
                Op::Delete(id) => {
                    table.remove(id.as_str())?;
                }
            }
        }
    }
    txn.commit()?;
    Ok(())
}
