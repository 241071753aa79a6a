//! The model a scene's browser page draws: the glTF the scene was baked from, as one GLB.
//!
//! It comes from the baked file's `MODL` section; a file baked without it (an older bounce, or
//! `--no-model`) can get one from `NAME.glb` or `NAME.gltf` beside `NAME.bounce`, packed here
//! when the scene is loaded or reloaded. The bytes are shared by every request.
//!
//! Either way the model is served to anyone who can read the scene, so it is checked first
//! ([`validate_packed`]: one GLB of at most [`MAX_SERVED_MODEL_BYTES`], valid glTF, no URI,
//! images of the type they claim): a file baked by an older bounce may hold whatever its glTF's
//! URIs named (`/etc/passwd` as an "image"), and a sibling glTF resolves its URIs only beneath its
//! own directory, as at bake time. A model that fails is logged and not served; the scene's
//! light still is.

use std::fmt;
use std::path::{Path, PathBuf};

use bounce_core::import::{MAX_SERVED_MODEL_BYTES, pack_glb, validate_packed};
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

/// The model of the scene in `baked_path`: `from_file` (its `MODL` section) if it has one that
/// passes [`validate_packed`], else the first sibling glTF that packs and passes. A model that
/// fails is logged and skipped: the scene still serves its light, only the page lacks a model.
pub fn load(baked_path: &Path, from_file: Option<Vec<u8>>) -> Option<SceneModel> {
    if let Some(bytes) = from_file {
        match validate_packed(&bytes) {
            Ok(()) => return Some(SceneModel::new(Bytes::from(bytes), ModelSource::Baked)),
            Err(e) => warn!(
                file = %baked_path.display(),
                error = %e,
                "the model in the baked file is refused and not served (bake the scene again)"
            ),
        }
    }
    for candidate in sibling_candidates(baked_path) {
        if !candidate.is_file() {
            continue;
        }
        match sibling(&candidate) {
            Ok(bytes) => {
                return Some(SceneModel::new(
                    Bytes::from(bytes),
                    ModelSource::Sibling(candidate),
                ));
            }
            Err(error) => {
                warn!(file = %candidate.display(), %error, "model beside the baked file refused and not served")
            }
        }
    }
    None
}

/// A glTF beside a baked file, packed and checked.
fn sibling(path: &Path) -> Result<Vec<u8>, String> {
    // Before reading it: packing holds the whole file, and more, in memory.
    let len = std::fs::metadata(path).map_err(|e| e.to_string())?.len();
    if len > MAX_SERVED_MODEL_BYTES {
        return Err(format!(
            "{len} bytes, over the limit of {MAX_SERVED_MODEL_BYTES} for a served model"
        ));
    }
    let bytes = pack_glb(path).map_err(|e| e.to_string())?;
    validate_packed(&bytes).map_err(|e| e.to_string())?;
    Ok(bytes)
}
