//! Emissive surfaces as run-time lights: which transport rows each emissive glTF material
//! covers, so a session can change a material's colour and strength and the change enters `B0`
//! (docs/design.md §1: `B0 = L_e + ρ ⊙ E_direct`) on exactly the rows it covers.
//!
//! A row's baked emission is the area-weighted mean of its pieces' triangles' emission, and a
//! triangle's emission is its material's `F = emissiveFactor × strength` times the emissive
//! texture averaged over the triangle (`t`, per channel; 1 without a texture). So per row `r`
//! and emissive material `g` the bake keeps the weight
//!
//! ```text
//! w_rg = Σ_{pieces of r made of g} area · t  /  Σ_{pieces of r} area
//! ```
//!
//! and `L_e,r = Σ_g w_rg ⊙ F_g` (plus nothing: a row's other pieces do not emit). A light set
//! that sets `g` to `F'_g` changes the row to `L_e,r + Σ_g w_rg ⊙ (F'_g − F_g)`: linear in the
//! change, exact for the rows' means, and zero work for rows no emitter covers. Where `F_g` has a
//! zero channel the texture's share of that channel is unknown (glTF multiplies it away), and
//! the other channels' mean stands for it: exact for untextured emitters, whose `t` is 1.
//!
//! A group is one emissive material on one glTF node (the importer gives each such pair its own
//! material entry, [`crate::scene::MaterialInfo::node`]), so a change may name a material (every
//! node made of it), a node (every emissive material it places) or both
//! ([`crate::light::EmissiveChange::reaches`]): two lamps sharing a shade's material are
//! switched apart by their nodes. Two materials of one name are two groups, and a change by
//! that name changes both. This module owns the weights, their checks and what a light set's
//! changes make of them; the `EMIT` section's bytes are [`crate::format`]'s, and the light JSON is
//! `bounce_types::light`'s.

use crate::light::{EmissiveChange, LightError, LightSet, MAX_NAME_BYTES};
use glam::{DVec3, Vec3};

use crate::patch::Pieces;
use crate::scene::Scene;

/// One emissive material of the scene on one node.
#[derive(Debug, Clone, PartialEq)]
pub struct EmitterGroup {
    /// The glTF material's name (`material #i` for an unnamed one, as the importer names it).
    pub name: String,
    /// The glTF node that places it (`node #i` for an unnamed one); `None` in a file from
    /// before emitters knew their nodes (format version 10), which a change by node cannot
    /// reach.
    pub node: Option<String>,
    /// glTF's `emissiveFactor`.
    pub color: [f32; 3],
    /// `KHR_materials_emissive_strength` (1 without it).
    pub strength: f32,
}

impl EmitterGroup {
    /// The emission the bake used: `color × strength`.
    pub fn emission(&self) -> Vec3 {
        Vec3::from(self.color) * self.strength
    }
}

/// One row's share of one group.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EmitterEntry {
    pub group: u32,
    /// `w_rg` per channel (module doc).
    pub weight: [f32; 3],
}

/// The scene's emissive materials and, per transport row, the weights of those covering it
/// (compressed rows: row `r` holds `entries[row_ptr[r]..row_ptr[r + 1]]`, groups ascending).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Emitters {
    pub groups: Vec<EmitterGroup>,
    pub row_ptr: Vec<u32>,
    pub entries: Vec<EmitterEntry>,
}

/// A triangle's emission over its material's, per channel: the emissive texture's average over
/// the triangle. A channel the material does not emit in takes the others' mean (module doc).
fn texture_share(tri_emission: Vec3, material: Vec3) -> DVec3 {
    let (e, f) = (tri_emission.as_dvec3(), material.as_dvec3());
    let mut share = [0.0f64; 3];
    let mut lit = Vec::with_capacity(3);
    for c in 0..3 {
        if f[c] > 0.0 {
            share[c] = (e[c] / f[c]).max(0.0);
            lit.push(share[c]);
        }
    }
    let mean = if lit.is_empty() {
        0.0
    } else {
        lit.iter().sum::<f64>() / lit.len() as f64
    };
    for c in 0..3 {
        if f[c] <= 0.0 {
            share[c] = mean;
        }
    }
    DVec3::from(share)
}

impl Emitters {
    /// The weights of `scene`'s emissive materials over the rows whose pieces `pieces` holds.
    /// Only materials that cover some row are groups; a scene without emissive surfaces has
    /// none, and every row is empty. A material whose name a light set could not give (empty,
    /// or longer than a light's names may be) is no group: its surfaces keep their baked
    /// emission, and the bake does not fail over a name.
    pub fn of_pieces(scene: &Scene, pieces: &Pieces) -> Emitters {
        let addressable = |name: &str| !name.is_empty() && name.len() <= MAX_NAME_BYTES;
        let emissive: Vec<bool> = scene
            .materials
            .iter()
            .map(|m| {
                Vec3::from(m.emission).max_element() > 0.0
                    && addressable(&m.name)
                    && m.node.as_deref().is_none_or(addressable)
            })
            .collect();
        let mut group_of: Vec<Option<u32>> = vec![None; scene.materials.len()];
        let mut groups = Vec::new();
        let mut row_ptr = vec![0u32];
        let mut entries = Vec::new();
        let mut acc: Vec<(u32, DVec3)> = Vec::new();
        for r in 0..pieces.patch_count() {
            acc.clear();
            let mut total = 0.0f64;
            for p in pieces.of(r) {
                let area = f64::from(p.area);
                total += area;
                let Some(tri) = scene.triangles.get(p.triangle as usize) else {
                    continue;
                };
                let m = tri.material as usize;
                if !emissive.get(m).copied().unwrap_or(false) {
                    continue;
                }
                let info = &scene.materials[m];
                let g = *group_of[m].get_or_insert_with(|| {
                    let strength = info.emissive_strength;
                    let color = if strength > 0.0 {
                        (Vec3::from(info.emission) / strength).to_array()
                    } else {
                        info.emission
                    };
                    groups.push(EmitterGroup {
                        name: info.name.clone(),
                        node: info.node.clone(),
                        color,
                        strength: if strength > 0.0 { strength } else { 1.0 },
                    });
                    groups.len() as u32 - 1
                });
                let share = texture_share(tri.emission, Vec3::from(info.emission)) * area;
                match acc.iter_mut().find(|(k, _)| *k == g) {
                    Some((_, w)) => *w += share,
                    None => acc.push((g, share)),
                }
            }
            acc.sort_by_key(|&(g, _)| g);
            if total > 0.0 {
                for &(group, w) in &acc {
                    entries.push(EmitterEntry {
                        group,
                        weight: (w / total).as_vec3().to_array(),
                    });
                }
            }
            row_ptr.push(entries.len() as u32);
        }
        Emitters {
            groups,
            row_ptr,
            entries,
        }
    }

    pub fn rows(&self) -> usize {
        self.row_ptr.len().saturating_sub(1)
    }

    /// Row `r`'s entries.
    pub fn row(&self, r: usize) -> &[EmitterEntry] {
        &self.entries[self.row_ptr[r] as usize..self.row_ptr[r + 1] as usize]
    }

    /// Why these weights do not fit a transport of `rows` rows, if they do not: offsets in
    /// order, groups in range and ascending within a row, weights finite and in `[0, 1]` (a
    /// share of the row's area, up to rounding), groups named and emitting something.
    pub fn check(&self, rows: usize) -> Result<(), String> {
        for (i, g) in self.groups.iter().enumerate() {
            for name in std::iter::once(&g.name).chain(&g.node) {
                if name.is_empty() || name.len() > MAX_NAME_BYTES {
                    return Err(format!("group {i}'s name has {} bytes", name.len()));
                }
            }
            if !(g.color.iter().all(|c| c.is_finite() && *c >= 0.0)
                && g.strength.is_finite()
                && g.strength > 0.0
                && g.emission().max_element() > 0.0
                && g.emission().is_finite())
            {
                return Err(format!(
                    "group {i} ('{}') emits nothing usable: color {:?}, strength {}",
                    g.name, g.color, g.strength
                ));
            }
        }
        if self.groups.iter().any(|g| g.node.is_some())
            && self.groups.iter().any(|g| g.node.is_none())
        {
            return Err("some groups name their node and some do not".into());
        }
        if self.rows() != rows {
            return Err(format!(
                "{} rows, but the transport has {rows}",
                self.rows()
            ));
        }
        if self.row_ptr.first() != Some(&0)
            || self.row_ptr.last().copied() != Some(self.entries.len() as u32)
        {
            return Err(format!(
                "the row offsets run from {:?} to {:?}, with {} entries",
                self.row_ptr.first(),
                self.row_ptr.last(),
                self.entries.len()
            ));
        }
        if let Some(r) = self.row_ptr.windows(2).position(|w| w[0] > w[1]) {
            return Err(format!("row {r}'s offsets decrease"));
        }
        for r in 0..rows {
            let row = self.row(r);
            if let Some(w) = row.windows(2).find(|w| w[0].group >= w[1].group) {
                return Err(format!(
                    "row {r}'s groups are not strictly ascending ({} then {})",
                    w[0].group, w[1].group
                ));
            }
            for e in row {
                if e.group as usize >= self.groups.len() {
                    return Err(format!(
                        "row {r} names group {}, past the {} there are",
                        e.group,
                        self.groups.len()
                    ));
                }
                if !e
                    .weight
                    .iter()
                    .all(|w| w.is_finite() && (0.0..=1.0 + 1e-4).contains(w))
                {
                    return Err(format!(
                        "row {r} gives group {} the weight {:?}, not a share of its area",
                        e.group, e.weight
                    ));
                }
            }
        }
        Ok(())
    }

    /// The groups a light set's changes reach, each with its new emission, in the set's order
    /// (a later change to a group wins), or the first change that reaches no group (the error's
    /// path is the light's, `lights[i].material` or `lights[i].node`).
    pub fn resolve(&self, set: &LightSet) -> Result<Vec<(usize, Vec3)>, LightError> {
        let mut out = Vec::new();
        for (i, change) in set.emissive_indexed() {
            let before = out.len();
            for (g, group) in self.groups.iter().enumerate() {
                if change.reaches(&group.name, group.node.as_deref()) {
                    let color = Vec3::from(change.color.unwrap_or(group.color));
                    out.push((g, color * change.strength.unwrap_or(group.strength)));
                }
            }
            if out.len() == before {
                return Err(unknown_emitter(i, &change, Some(&self.names())));
            }
        }
        Ok(out)
    }

    /// Each row's emission under `set`: `baked[r]` (the rows' baked `L_e`) changed by the set's
    /// emissive changes, or `None` when the set changes nothing (the caller keeps `baked`).
    /// Kept finite and non-negative, as direct light is.
    pub fn emission(
        &self,
        baked: impl Iterator<Item = [f32; 3]>,
        set: &LightSet,
    ) -> Result<Option<Vec<[f32; 3]>>, LightError> {
        let changes = self.resolve(set)?;
        if changes.is_empty() {
            return Ok(None);
        }
        let mut delta = vec![Vec3::ZERO; self.groups.len()];
        for &(g, emission) in &changes {
            delta[g] = emission - self.groups[g].emission();
        }
        Ok(Some(
            baked
                .enumerate()
                .map(|(r, base)| {
                    let mut e = Vec3::from(base);
                    if r < self.rows() {
                        for entry in self.row(r) {
                            e += Vec3::from(entry.weight) * delta[entry.group as usize];
                        }
                    }
                    e.clamp(Vec3::ZERO, Vec3::splat(f32::MAX)).to_array()
                })
                .collect(),
        ))
    }

    /// The rows' concatenation (shards of one bake, in row order): the groups are every
    /// shard's, which must agree.
    pub fn concat(parts: impl IntoIterator<Item = Emitters>) -> Result<Emitters, String> {
        let mut out: Option<Emitters> = None;
        for p in parts {
            match &mut out {
                None => out = Some(p),
                Some(o) => {
                    if o.groups != p.groups {
                        return Err("shards list different emissive materials".into());
                    }
                    let base = o.entries.len() as u32;
                    o.row_ptr
                        .extend(p.row_ptr.iter().skip(1).map(|&x| base + x));
                    o.entries.extend(p.entries);
                }
            }
        }
        Ok(out.unwrap_or(Emitters {
            row_ptr: vec![0],
            ..Emitters::default()
        }))
    }
}

/// One group's names: what a change can reach it by.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EmitterName {
    pub material: String,
    /// `None` in a file from before emitters knew their nodes.
    pub node: Option<String>,
}

/// The distinct materials of `names`, in order.
pub fn materials_of(names: &[EmitterName]) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for n in names {
        if !out.contains(&n.material) {
            out.push(n.material.clone());
        }
    }
    out
}

/// The distinct nodes of `names`, in order.
pub fn nodes_of(names: &[EmitterName]) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for n in names.iter().filter_map(|n| n.node.as_ref()) {
        if !out.contains(n) {
            out.push(n.clone());
        }
    }
    out
}

/// The error for an emissive change (light `index`) reaching no emitter of the scene, whose
/// emitters are `names` (`None` for a file that lists none, baked before emitters were kept).
pub fn unknown_emitter(
    index: usize,
    change: &EmissiveChange<'_>,
    names: Option<&[EmitterName]>,
) -> LightError {
    let what = change.describe();
    let reason = match names {
        None => "this baked file lists no emitters (it predates them: bake it again to change \
                 emissive surfaces at run time)"
            .to_string(),
        Some([]) => format!("the scene has no {what} (it has none)"),
        Some(names) if change.node.is_some() && names.iter().all(|n| n.node.is_none()) => {
            format!(
                "the scene has no {what}: this baked file does not know its emitters' nodes (it \
                 predates them: bake it again to change emitters by node; its emissive \
                 materials: {})",
                materials_of(names).join(", ")
            )
        }
        Some(names) => {
            let nodes = nodes_of(names);
            format!(
                "the scene has no {what} (its emissive materials: {}{})",
                materials_of(names).join(", "),
                if nodes.is_empty() {
                    String::new()
                } else {
                    format!("; on nodes: {}", nodes.join(", "))
                }
            )
        }
    };
    LightError::Invalid {
        path: format!("lights[{index}].{}", change.field()),
        reason,
    }
}

impl Emitters {
    /// Each group's names, each pair once, in the order of the groups.
    pub fn names(&self) -> Vec<EmitterName> {
        let mut out: Vec<EmitterName> = Vec::with_capacity(self.groups.len());
        for g in &self.groups {
            let name = EmitterName {
                material: g.name.clone(),
                node: g.node.clone(),
            };
            if !out.contains(&name) {
                out.push(name);
            }
        }
        out
    }
}

/// Checks that every emissive change of `set` reaches one of a scene's emitters, `names`
/// ([`Emitters::names`]; `None` for a file that lists none), as [`Emitters::resolve`] would:
/// what a server checks when a session's lights are set, before any relight.
pub fn check_names(names: Option<&[EmitterName]>, set: &LightSet) -> Result<(), LightError> {
    for (i, change) in set.emissive_indexed() {
        let known = names.is_some_and(|names| {
            names
                .iter()
                .any(|n| change.reaches(&n.material, n.node.as_deref()))
        });
        if !known {
            return Err(unknown_emitter(i, &change, names));
        }
    }
    Ok(())
}

/// `scene` with `set`'s emissive changes applied to its triangles, each keeping its texture's
/// share ([`texture_share`]), as the reference path tracer needs them; refused as
/// [`Emitters::resolve`] refuses, naming the emissive materials the scene has.
pub fn apply_to_scene(scene: &mut Scene, set: &LightSet) -> Result<(), LightError> {
    let mut new: Vec<Option<Vec3>> = vec![None; scene.materials.len()];
    for (i, change) in set.emissive_indexed() {
        let mut found = false;
        for (m, info) in scene.materials.iter().enumerate() {
            let baked = Vec3::from(info.emission);
            if change.reaches(&info.name, info.node.as_deref()) && baked.max_element() > 0.0 {
                let s = if info.emissive_strength > 0.0 {
                    info.emissive_strength
                } else {
                    1.0
                };
                let c = change.color.map_or(baked / s, Vec3::from);
                new[m] = Some(c * change.strength.unwrap_or(s));
                found = true;
            }
        }
        if !found {
            let names: Vec<EmitterName> = scene
                .materials
                .iter()
                .filter(|m| Vec3::from(m.emission).max_element() > 0.0)
                .map(|m| EmitterName {
                    material: m.name.clone(),
                    node: m.node.clone(),
                })
                .collect();
            return Err(unknown_emitter(i, &change, Some(&names)));
        }
    }
    for tri in &mut scene.triangles {
        if let Some(Some(f)) = new.get(tri.material as usize) {
            let baked = Vec3::from(scene.materials[tri.material as usize].emission);
            let share = texture_share(tri.emission, baked).as_vec3();
            tri.emission = (share * *f).min(Vec3::splat(f32::MAX));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::patch::PieceTri;
    use crate::scene::{MaterialInfo, Triangle};

    fn material(name: &str, emission: [f32; 3]) -> MaterialInfo {
        MaterialInfo {
            name: name.into(),
            base_color_factor: [0.5; 3],
            has_base_color_texture: false,
            emission,
            emissive_strength: 2.0,
            double_sided: false,
            node: None,
        }
    }

    /// Three unit triangles in one row: a lamp, a material whose name is too long to address,
    /// and a plain wall.
    #[test]
    fn weights_are_area_shares_and_unaddressable_names_are_no_group() {
        let long = "n".repeat(MAX_NAME_BYTES + 1);
        let tri = |material: u32, emission: Vec3| Triangle {
            positions: [Vec3::ZERO, Vec3::X, Vec3::Y],
            albedo: Vec3::splat(0.5),
            emission,
            double_sided: false,
            material,
        };
        let scene = Scene {
            triangles: vec![
                tri(0, Vec3::new(4.0, 2.0, 0.0)),
                tri(1, Vec3::ONE),
                tri(2, Vec3::ZERO),
            ],
            materials: vec![
                material("Lamp", [4.0, 2.0, 0.0]),
                material(&long, [1.0; 3]),
                material("Wall", [0.0; 3]),
            ],
            ..Scene::default()
        };
        let piece = |triangle: u32, area: f32| PieceTri {
            corners: [Vec3::ZERO, Vec3::X, Vec3::Y],
            normal: Vec3::Z,
            area,
            triangle,
        };
        let pieces = Pieces {
            start: vec![0, 3],
            tris: vec![piece(0, 1.0), piece(1, 1.0), piece(2, 2.0)],
        };
        let e = Emitters::of_pieces(&scene, &pieces);
        e.check(1).unwrap();
        assert_eq!(materials_of(&e.names()), vec!["Lamp".to_string()]);
        assert_eq!(e.groups[0].color, [2.0, 1.0, 0.0]);
        assert_eq!(e.groups[0].strength, 2.0);
        // A quarter of the row's area; the blue channel the lamp does not emit takes the
        // others' share.
        assert_eq!(
            e.row(0),
            &[EmitterEntry {
                group: 0,
                weight: [0.25; 3]
            }]
        );
        let set = LightSet::from_json(
            r#"{"lights": [{"type": "emissive", "material": "Lamp", "color": [0, 0, 1]}]}"#,
        )
        .unwrap();
        // The row's baked emission: the lamp's quarter and the unaddressable one's quarter.
        let baked = [[1.25, 0.75, 0.25]];
        let changed = e.emission(baked.into_iter(), &set).unwrap().unwrap();
        // The lamp now emits (0, 0, 2) over its quarter; the other quarter is as baked.
        assert_eq!(changed, vec![[0.25, 0.25, 0.75]]);
    }
}
