//! The scene directory: every `*.bounce` file in it is a scene named after its file stem.
//!
//! Reading is separate from loading onto the engine so that a bad file is reported and skipped
//! (the other scenes still serve) before any device work starts.

use std::path::{Path, PathBuf};

use bounce_core::format::Baked;
use bounce_core::patch::PatchLayout;

use crate::error::{ServerError, SkippedScene};

/// What the service knows about a scene without the engine: its name and layout.
#[derive(Debug, Clone)]
pub struct SceneInfo {
    pub name: String,
    pub path: PathBuf,
    pub codec: String,
    pub layout: PatchLayout,
}

/// A scene read from disk, not yet on the engine.
pub(crate) struct ReadScene {
    pub info: SceneInfo,
    pub baked: Baked,
}

/// Reads every `*.bounce` file of `dir`, in name order. Files that fail to read are returned
/// apart, so the caller can log them; no readable file at all is an error.
pub(crate) fn read_dir(dir: &Path) -> Result<(Vec<ReadScene>, Vec<SkippedScene>), ServerError> {
    let io = |source| ServerError::ScenesDir {
        path: dir.to_path_buf(),
        source,
    };
    let mut paths = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let path = entry.map_err(io)?.path();
        if path.extension().is_some_and(|e| e == "bounce") && path.is_file() {
            paths.push(path);
        }
    }
    paths.sort();
    let mut scenes = Vec::new();
    let mut skipped = Vec::new();
    for path in paths {
        let Some(name) = path.file_stem().and_then(|s| s.to_str()).map(str::to_owned) else {
            continue;
        };
        match Baked::read(&path) {
            Ok(baked) => scenes.push(ReadScene {
                info: SceneInfo {
                    name,
                    path,
                    codec: baked.transport.codec.clone(),
                    layout: baked.layout.clone(),
                },
                baked,
            }),
            Err(source) => skipped.push(SkippedScene { path, source }),
        }
    }
    if scenes.is_empty() {
        return Err(ServerError::NoScenes(dir.to_path_buf()));
    }
    Ok((scenes, skipped))
}
