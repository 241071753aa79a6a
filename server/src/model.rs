//! The model a scene's browser page draws: the glTF the scene was baked from, as one GLB.
//!
//! It comes from the baked file's `MODL` section; a file baked without it (an older bounce, or
//! `--no-model`) can get one from `NAME.glb` or `NAME.gltf` beside `NAME.bounce`, packed here
//! when the scene is loaded or reloaded. The bytes are shared by every request.

use std::fmt;
use std::path::{Path, PathBuf};

use bounce_core::import::pack_glb;
use bytes::Bytes;
use tracing::warn;

use crate::cache::etag_of;

/// A scene's model, ready to send.
pub struct SceneModel {
    pub bytes: Bytes,
    /// Strong tag of the bytes, quoted.
    pub etag: String,
    pub source: ModelSource,
}

/// Where a scene's model came from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ModelSource {
    /// The baked file's `MODL` section.
    Baked,
    /// A glTF file beside the baked file, packed on load.
    Sibling(PathBuf),
}

impl fmt::Debug for SceneModel {
    // Not the bytes: a model is megabytes.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("SceneModel")
            .field("bytes", &self.bytes.len())
            .field("etag", &self.etag)
            .field("source", &self.source)
            .finish()
    }
}

impl SceneModel {
    fn new(bytes: Bytes, source: ModelSource) -> SceneModel {
        SceneModel {
            etag: etag_of(&bytes),
            bytes,
            source,
        }
    }
}

/// The files beside `baked_path` a model may come from, in the order tried.
pub fn sibling_candidates(baked_path: &Path) -> [PathBuf; 2] {
    [
        baked_path.with_extension("glb"),
        baked_path.with_extension("gltf"),
    ]
}

/// The model of the scene in `baked_path`: `from_file` (its `MODL` section) if it has one, else
/// the first sibling glTF that packs. A sibling that fails to pack is logged and skipped: the
/// scene still serves its light, only the page lacks a model.
pub fn load(baked_path: &Path, from_file: Option<Vec<u8>>) -> Option<SceneModel> {
    if let Some(bytes) = from_file {
        return Some(SceneModel::new(Bytes::from(bytes), ModelSource::Baked));
    }
    for candidate in sibling_candidates(baked_path) {
        if !candidate.is_file() {
            continue;
        }
        match pack_glb(&candidate) {
            Ok(bytes) => {
                return Some(SceneModel::new(
                    Bytes::from(bytes),
                    ModelSource::Sibling(candidate),
                ));
            }
            Err(e) => {
                warn!(file = %candidate.display(), error = %e, "model beside the baked file not usable")
            }
        }
    }
    None
}
