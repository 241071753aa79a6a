//! The scene directory: every `*.bounce` file in it is a scene named after its file stem.
//!
//! Reading is separate from loading onto the engine so that a bad file is reported and skipped
//! (the other scenes still serve) before any device work starts.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::SystemTime;

use bounce_core::format::Baked;
use bounce_core::patch::PatchLayout;

use crate::error::{ServerError, SkippedScene};
use crate::model::{self, SceneModel};

/// What the service knows about a scene without the engine: its name, layout and model.
#[derive(Debug, Clone)]
pub struct SceneInfo {
    pub name: String,
    pub path: PathBuf,
    pub codec: String,
    pub layout: PatchLayout,
    /// What the browser page draws ([`crate::model`]); `None` when neither the baked file nor a
    /// glTF beside it has one.
    pub model: Option<Arc<SceneModel>>,
    /// Whether the file has each row's view of the sky, without which a session's sky adds
    /// nothing (a file from before format version 5).
    pub sky_view: bool,
    /// The emitters a light set may change, by material and node; `None` for a file baked
    /// before emitters were kept (format version 6) or a voxel-face bake.
    pub emitters: Option<Vec<bounce_core::emitter::EmitterName>>,
    /// Where the scene's irradiance probes are; empty for a file baked without them.
    pub probes: Vec<[f32; 3]>,
}

impl SceneInfo {
    /// The scene in `baked`, read from `path`. Takes the model out of `baked` (the engine has no
    /// use for it) or, lacking one, looks for a glTF beside `path`.
    pub fn new(name: String, path: PathBuf, baked: &mut Baked) -> SceneInfo {
        let model = model::load(&path, baked.model.take()).map(Arc::new);
        if baked.sky.is_none() {
            tracing::warn!(
                scene = %name,
                file = %path.display(),
                "the baked file has no sky visibility (older than format version 5): a sky adds \
                 nothing to this scene; bake it again"
            );
        }
        SceneInfo {
            name,
            path,
            codec: baked.transport.codec.clone(),
            layout: baked.layout.clone(),
            model,
            sky_view: baked.sky.is_some(),
            emitters: baked.emitters.as_ref().map(|e| e.names()),
            probes: baked
                .probes
                .as_ref()
                .map(|p| p.positions.clone())
                .unwrap_or_default(),
        }
    }

    /// The layout as the wire sends it, for gRPC and (as JSON) HTTP alike.
    pub fn wire_layout(&self) -> bounce_wire::proto::Layout {
        let l = &self.layout;
        bounce_wire::layout::to_proto(
            &self.name,
            l.origin,
            l.voxel_size,
            l.dims,
            l.patches.iter().map(|p| (p.voxel, p.face)),
            &self.probes,
        )
    }
}

/// A scene read from disk, not yet on the engine.
pub(crate) struct ReadScene {
    pub info: SceneInfo,
    pub baked: Baked,
    pub stamp: Stamp,
}

/// What tells that a file changed: its modification time and length.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Stamp {
    modified: Option<SystemTime>,
    len: u64,
}

pub fn stamp(path: &Path) -> std::io::Result<Stamp> {
    let m = std::fs::metadata(path)?;
    Ok(Stamp {
        modified: m.modified().ok(),
        len: m.len(),
    })
}

/// The scene name of a baked file: its stem.
pub fn scene_name(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

fn baked_files(dir: &Path) -> std::io::Result<Vec<PathBuf>> {
    let mut paths = Vec::new();
    for entry in std::fs::read_dir(dir)? {
        let path = entry?.path();
        if path.extension().is_some_and(|e| e == "bounce") && path.is_file() {
            paths.push(path);
        }
    }
    paths.sort();
    Ok(paths)
}

/// The baked files of `dir` that are new or changed since `known`, which is updated. A file
/// caught half-written fails validation and is reported; once complete its stamp differs and it
/// is tried again. (Writers should still write a temporary file and rename it.)
pub(crate) fn changed_files(dir: &Path, known: &mut HashMap<PathBuf, Stamp>) -> Vec<PathBuf> {
    let Ok(paths) = baked_files(dir) else {
        return Vec::new();
    };
    let mut changed = Vec::new();
    for path in paths {
        let Ok(now) = stamp(&path) else { continue };
        if known.get(&path) != Some(&now) {
            known.insert(path.clone(), now);
            changed.push(path);
        }
    }
    changed
}

/// Reads every `*.bounce` file of `dir`, in name order. Files that fail to read are returned
/// apart, so the caller can log them; no readable file at all is an error.
pub(crate) fn read_dir(dir: &Path) -> Result<(Vec<ReadScene>, Vec<SkippedScene>), ServerError> {
    let io = |source| ServerError::ScenesDir {
        path: dir.to_path_buf(),
        source,
    };
    let paths = baked_files(dir).map_err(io)?;
    let mut scenes = Vec::new();
    let mut skipped = Vec::new();
    for path in paths {
        let Some(name) = path.file_stem().and_then(|s| s.to_str()).map(str::to_owned) else {
            continue;
        };
        // Stamped before reading, so a write that lands meanwhile is seen as a change.
        let Ok(stamp) = stamp(&path) else { continue };
        match Baked::read(&path) {
            Ok(mut baked) => scenes.push(ReadScene {
                info: SceneInfo::new(name, path, &mut baked),
                baked,
                stamp,
            }),
            Err(source) => skipped.push(SkippedScene { path, source }),
        }
    }
    if scenes.is_empty() {
        return Err(ServerError::NoScenes(dir.to_path_buf()));
    }
    Ok((scenes, skipped))
}
