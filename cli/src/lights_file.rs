//! Light configuration files (`{"lights": [...]}`) as every command reads them.

use std::path::Path;

use anyhow::{Context, Result, bail};
use bounce_core::format::Baked;
use bounce_core::light::LightSet;
use bounce_core::scene::Scene;

/// Reads and validates one light configuration file; errors name the file.
pub fn read(path: &Path) -> Result<LightSet> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    LightSet::from_json(&text).with_context(|| format!("{}", path.display()))
}

/// The lights of `path`, or the scene's own when no file is given.
pub fn or_scene(path: Option<&Path>, scene: &Scene) -> Result<LightSet> {
    match path {
        Some(path) => read(path),
        None if scene.lights.is_empty() => {
            bail!(
                "the scene has no lights of its own: give a light configuration with --lights L.json"
            )
        }
        None => Ok(LightSet {
            lights: scene.lights.clone(),
        }),
    }
}

/// What to tell a user whose lights hold a sky that `baked` cannot take: a file baked before
/// the sky view (format version 5) has none, and a sky adds nothing to it.
pub fn sky_warning<'a>(
    baked: &Baked,
    file: &Path,
    sets: impl IntoIterator<Item = &'a LightSet>,
) -> Option<String> {
    let has_sky = sets.into_iter().any(|s| s.sky_sh().is_some());
    (has_sky && baked.sky.is_none()).then(|| {
        format!(
            "{} has no sky visibility (baked by a bounce older than format version 5): the sky \
             adds nothing to it; bake the scene again",
            file.display()
        )
    })
}
