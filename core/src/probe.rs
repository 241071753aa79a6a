//! Irradiance probes for objects that move through a scene (docs/design.md §2, "Probes").
//!
//! Patches light the surfaces the bake saw. A hand, a controller or an avatar is not among
//! them, yet it needs the same indirect light as the walls around it. So the bake places probes
//! in the scene's empty space near its surfaces and records, per probe and per each of the six
//! axis directions (the [`Face`] order, as the clients' six-direction volume), where
//! cosine-weighted rays about that direction land: the share of the rays that meet each
//! transport row. That is a sparse gather matrix `G` (row `6 · probe + direction`, columns the
//! transport's rows), and a relight gives every probe direction the irradiance
//!
//! ```text
//! E_probe = G · B,    B = B0 + ρ ⊙ E_ind
//! ```
//!
//! from the rows' exitance: their emission and direct light reflected (`B0`), and the indirect
//! light they reflect. A diffuse row of exitance `B` has radiance `B / π`, and cosine-weighted
//! rays estimate `E = π · mean(L)`, so each ray that lands on row `j` adds `B_j / R`. Rows sum
//! to at most 1 (escaped rays and back faces carry nothing), as the form factors' do.
//!
//! The rays that escape are the probe direction's view of the sky, kept as the rows' is
//! ([`crate::sky`]): `c_lm = (π / R) Σ_escaped Y_lm(ω)`, so under a sky of radiance
//! coefficients `L_lm` a probe direction also gets `E_sky = Σ c_lm L_lm`, the sky seen through
//! the openings. That is the light a moving object cannot draw itself, as the patches' frames
//! carry their sky's direct light.
//!
//! What this does not do: probes are as fine as `spacing`: an object between them gets a blend
//! of its neighbours (the client's job, trilinear over the grid or nearest).
//!
//! Placement is a regular grid of `spacing` over the voxel grid's box. A grid point is a probe
//! when its voxel is empty, an occupied voxel lies within `spacing` of it, at most 8 voxels (near
//! surfaces: space far from every surface holds nothing to light), and a short sphere of test
//! rays says it is inside the scene: few of them meet the back of a one-sided surface (it would
//! be inside a wall or behind the level) and not most of them escape.

use std::ops::Range;

use glam::Vec3;
use rayon::prelude::*;

use crate::patch::PatchLayout;
use crate::rays::RayFate;
use crate::sky::{SkySum, SkyVisibility};
use crate::surface::{SurfaceScene, cosine_direction};
use bounce_types::face::Face;

/// Directions per probe: the six axis directions, in [`Face`] order.
pub const DIRECTIONS: usize = 6;
/// Rays a probe direction gathers with unless a bake asks otherwise.
pub const DEFAULT_PROBE_RAYS: u32 = 1024;
/// The grid spacing in voxels unless a bake gives one in scene units.
pub const DEFAULT_SPACING_VOXELS: f32 = 2.0;
/// The most grid points a placement considers: a finer spacing is refused, not run for hours.
pub const MAX_GRID_POINTS: u64 = 4_000_000;
/// The most probes a file holds.
pub const MAX_PROBES: usize = 1 << 18;
/// The most rays a probe direction takes (the Sobol sequence's index range).
pub const MAX_PROBE_RAYS: u32 = 1 << 16;
/// Test rays that decide whether a grid point is inside the scene.
const TEST_RAYS: u32 = 64;
/// A point where more than this share of test rays meets the back of a one-sided surface is
/// inside geometry or behind the level's walls.
const MAX_BACK_SHARE: f32 = 0.1;
/// A point where more than this share escapes is outside the scene.
const MAX_ESCAPED_SHARE: f32 = 0.75;
/// The farthest, in voxels, a probe may be from every occupied voxel.
const MAX_REACH: f32 = 8.0;
/// Sobol dimension sets: the gather's, and the test rays'.
const GATHER_SET: u32 = 0;
const TEST_SET: u32 = 1;

/// How a bake places probes and gathers at them. Recorded in the bake's settings, so that the
/// shards of a sharded bake can be checked to place the same probes.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ProbeOptions {
    /// Grid spacing in scene units; `None`: [`DEFAULT_SPACING_VOXELS`] voxels.
    pub spacing: Option<f32>,
    /// Rays per probe direction.
    pub rays: u32,
}

impl Default for ProbeOptions {
    fn default() -> Self {
        ProbeOptions {
            spacing: None,
            rays: DEFAULT_PROBE_RAYS,
        }
    }
}

impl ProbeOptions {
    /// Why these options cannot run, if they cannot.
    pub fn check(&self) -> Result<(), String> {
        if let Some(s) = self.spacing
            && !(s.is_finite() && s > 0.0)
        {
            return Err(format!(
                "--probe-spacing must be a positive length in scene units, not {s}"
            ));
        }
        if self.rays == 0 || self.rays > MAX_PROBE_RAYS {
            return Err(format!(
                "--probe-rays must be 1 to {MAX_PROBE_RAYS}, not {}",
                self.rays
            ));
        }
        Ok(())
    }
}

/// The probes of a bake and their gather matrix `G` in CSR form.
#[derive(Debug, Clone, PartialEq)]
pub struct Probes {
    /// The grid spacing they were placed at, scene units.
    pub spacing: f32,
    /// Rays each direction gathered with.
    pub rays: u32,
    /// World positions, one per probe.
    pub positions: Vec<[f32; 3]>,
    /// `6 · probes + 1` offsets into `cols` and `values`, from 0, non-decreasing.
    pub row_ptr: Vec<u32>,
    /// Per entry, the transport row met: strictly ascending within a row.
    pub cols: Vec<u32>,
    /// Per entry, the share of the direction's rays that met that row.
    pub values: Vec<f32>,
    /// Each probe direction's view of the sky from its rays that escaped (`6 · probe +
    /// direction`, [`crate::sky`]); `None` in a file from before it (format version 8), whose
    /// probes see no sky directly.
    pub sky: Option<SkyVisibility>,
}

impl Probes {
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Entries of `G`.
    pub fn nnz(&self) -> usize {
        self.cols.len()
    }

    /// Why this does not fit a transport of `rows` rows, if it does not: positions finite,
    /// offsets in order and in range, columns ascending and inside the rows, values finite and
    /// positive, each direction's sum at most 1 (a little over for f32 rounding).
    pub fn check(&self, rows: usize) -> Result<(), String> {
        check_placement(self.spacing, self.rays, &self.positions)?;
        let gathers = self.len() * DIRECTIONS;
        if self.row_ptr.len() != gathers + 1 {
            return Err(format!(
                "{} row offsets for {} probes (expected {})",
                self.row_ptr.len(),
                self.len(),
                gathers + 1
            ));
        }
        check_gathers(&self.row_ptr, &self.cols, &self.values, 0, rows)?;
        if let Some(sky) = &self.sky {
            sky.check(gathers)
                .map_err(|m| format!("the probes' sky view: {m}"))?;
        }
        Ok(())
    }

    /// Irradiance at every probe direction from a sky of radiance coefficients `sky`, through
    /// the directions' sky view: `None` without a view.
    pub fn sky_irradiance(
        &self,
        sky: &[[f32; 3]; bounce_types::sh::SH_COEFFICIENTS],
    ) -> Option<Vec<[f32; 3]>> {
        Some(self.sky.as_ref()?.irradiance(sky))
    }

    /// Irradiance at every probe direction (`6 · probe + direction`) from the rows' exitance
    /// `B` (one value per transport row).
    pub fn irradiance(&self, exitance: &[[f32; 3]]) -> Vec<[f32; 3]> {
        (0..self.len() * DIRECTIONS)
            .map(|r| {
                let lo = self.row_ptr[r] as usize;
                let hi = self.row_ptr[r + 1] as usize;
                let mut e = [0.0f32; 3];
                for (&c, &v) in self.cols[lo..hi].iter().zip(&self.values[lo..hi]) {
                    for (e, b) in e.iter_mut().zip(exitance[c as usize]) {
                        *e += v * b;
                    }
                }
                // Kept finite as the rows' light is.
                e.map(|v| v.min(f32::MAX))
            })
            .collect()
    }
}

/// The spacing, ray count and positions are what a file may hold.
fn check_placement(spacing: f32, rays: u32, positions: &[[f32; 3]]) -> Result<(), String> {
    if !(spacing.is_finite() && spacing > 0.0) {
        return Err(format!("spacing {spacing} is not a positive length"));
    }
    if rays == 0 || rays > MAX_PROBE_RAYS {
        return Err(format!("{rays} rays a direction"));
    }
    if positions.len() > MAX_PROBES {
        return Err(format!(
            "{} probes, the most is {MAX_PROBES}",
            positions.len()
        ));
    }
    if let Some(i) = positions
        .iter()
        .position(|p| !p.iter().all(|v| v.is_finite()))
    {
        return Err(format!("probe {i}'s position is not finite"));
    }
    Ok(())
}

/// Gather rows in CSR form (`row_ptr` one longer than the rows, the first of them gather row
/// `first`) over a transport of `rows` rows: offsets spanning the entries in order, columns
/// ascending within a row and inside the transport, values positive, each row's sum at most 1
/// (a little over for f32 rounding).
fn check_gathers(
    row_ptr: &[u32],
    cols: &[u32],
    values: &[f32],
    first: usize,
    rows: usize,
) -> Result<(), String> {
    if row_ptr.first() != Some(&0) || row_ptr.last().map(|&e| e as usize) != Some(cols.len()) {
        return Err("row offsets do not span the entries".into());
    }
    if cols.len() != values.len() {
        return Err("columns and values differ in count".into());
    }
    for (k, w) in row_ptr.windows(2).enumerate() {
        let r = first + k;
        let (lo, hi) = (w[0] as usize, w[1] as usize);
        if lo > hi || hi > cols.len() {
            return Err(format!("gather row {r}'s offsets are out of order"));
        }
        let row_cols = &cols[lo..hi];
        if row_cols.windows(2).any(|w| w[0] >= w[1]) {
            return Err(format!("gather row {r}'s columns are not ascending"));
        }
        if row_cols.last().is_some_and(|&c| c as usize >= rows) {
            return Err(format!(
                "gather row {r} names a transport row past the last ({rows})"
            ));
        }
        let row_values = &values[lo..hi];
        if row_values.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
            return Err(format!("gather row {r} has a value that is not positive"));
        }
        let sum: f64 = row_values.iter().map(|&v| f64::from(v)).sum();
        if sum > 1.0 + 1e-4 {
            return Err(format!("gather row {r} sums to {sum}, over 1"));
        }
    }
    Ok(())
}

/// A consecutive range of a bake's gather rows: what one shard of a sharded bake gathers and
/// carries ([`crate::bake::shard`]). Every shard places all the probes (placement depends only
/// on the scene, the options and the seed), so each carries every position and the merge can
/// check that they agree.
#[derive(Debug, Clone, PartialEq)]
pub struct ProbeRows {
    pub spacing: f32,
    pub rays: u32,
    /// Every probe's position, not only those of the rows held.
    pub positions: Vec<[f32; 3]>,
    /// The gather rows held (`6 · probe + direction`).
    pub range: Range<usize>,
    /// `range.len() + 1` offsets into `cols` and `values`, from 0.
    pub row_ptr: Vec<u32>,
    pub cols: Vec<u32>,
    pub values: Vec<f32>,
    /// The rows' view of the sky, one per row held.
    pub sky: SkyVisibility,
}

impl ProbeRows {
    /// Why these rows do not fit a transport of `rows` rows, if they do not: as
    /// [`Probes::check`], over the rows held, which lie within the probes' gather rows.
    pub fn check(&self, rows: usize) -> Result<(), String> {
        check_placement(self.spacing, self.rays, &self.positions)?;
        let gathers = self.positions.len() * DIRECTIONS;
        if self.range.start > self.range.end || self.range.end > gathers {
            return Err(format!(
                "gather rows {}..{} of {} probes' {gathers}",
                self.range.start,
                self.range.end,
                self.positions.len()
            ));
        }
        if self.row_ptr.len() != self.range.len() + 1 {
            return Err(format!(
                "{} row offsets for gather rows {}..{}",
                self.row_ptr.len(),
                self.range.start,
                self.range.end
            ));
        }
        check_gathers(
            &self.row_ptr,
            &self.cols,
            &self.values,
            self.range.start,
            rows,
        )?;
        self.sky
            .check(self.range.len())
            .map_err(|m| format!("the probes' sky view: {m}"))
    }

    /// Consecutive parts joined into the probes: each part's placement the same, their ranges
    /// in order, from the first gather row to the last.
    pub fn join(parts: impl IntoIterator<Item = ProbeRows>) -> Result<Probes, String> {
        let mut parts = parts.into_iter();
        let first = parts.next().ok_or("no probe rows")?;
        let mut probes = Probes {
            spacing: first.spacing,
            rays: first.rays,
            positions: first.positions.clone(),
            row_ptr: vec![0],
            cols: Vec::new(),
            values: Vec::new(),
            sky: Some(SkyVisibility { rows: Vec::new() }),
        };
        let mut end = 0;
        for part in std::iter::once(first).chain(parts) {
            if (part.spacing, part.rays) != (probes.spacing, probes.rays)
                || part.positions != probes.positions
            {
                return Err("the parts placed different probes".into());
            }
            if part.range.start != end {
                return Err(format!(
                    "gather rows {}..{} follow row {end}",
                    part.range.start, part.range.end
                ));
            }
            end = part.range.end;
            let base = probes.cols.len() as u32;
            probes
                .row_ptr
                .extend(part.row_ptr[1..].iter().map(|&p| base + p));
            probes.cols.extend(part.cols);
            probes.values.extend(part.values);
            if let Some(sky) = probes.sky.as_mut() {
                sky.rows.extend(part.sky.rows);
            }
        }
        if end != probes.len() * DIRECTIONS {
            return Err(format!(
                "the parts end at gather row {end} of {}",
                probes.len() * DIRECTIONS
            ));
        }
        Ok(probes)
    }
}

impl Probes {
    /// Gather rows `range` of these probes, with every position. `None` when the probes have
    /// no sky view (a file from before it), which a bake's never lack.
    pub fn rows(&self, range: Range<usize>) -> Option<ProbeRows> {
        let (lo, hi) = (self.row_ptr[range.start], self.row_ptr[range.end]);
        Some(ProbeRows {
            spacing: self.spacing,
            rays: self.rays,
            positions: self.positions.clone(),
            row_ptr: self.row_ptr[range.start..=range.end]
                .iter()
                .map(|&p| p - lo)
                .collect(),
            cols: self.cols[lo as usize..hi as usize].to_vec(),
            values: self.values[lo as usize..hi as usize].to_vec(),
            sky: self.sky.as_ref()?.slice(range.clone()),
            range,
        })
    }
}

/// Why probes cannot be placed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProbeError {
    #[error(
        "--probe-spacing {spacing} puts {points} grid points over the scene, more than \
         {MAX_GRID_POINTS}: choose a larger spacing"
    )]
    TooFine { spacing: f32, points: u64 },
    #[error(
        "{probes} probes at spacing {spacing}, more than a file holds ({MAX_PROBES}): choose a \
         larger --probe-spacing"
    )]
    TooMany { spacing: f32, probes: usize },
}

/// Places probes over `layout`'s grid (the transport's, whose occupancy is `occupied`: linear
/// voxel indices, ascending) and gathers at them through `scene`. Depends only on its inputs and
/// `seed`, not on the thread count.
pub fn bake_probes(
    layout: &PatchLayout,
    occupied: &[u64],
    scene: &SurfaceScene,
    options: &ProbeOptions,
    seed: u64,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Probes, ProbeError> {
    let placed = place_probes(layout, occupied, scene, options, seed)?;
    let all = 0..placed.positions.len() * DIRECTIONS;
    let ProbeRows {
        spacing,
        rays,
        positions,
        row_ptr,
        cols,
        values,
        sky,
        ..
    } = gather_rows(scene, placed, all, seed, progress);
    Ok(Probes {
        spacing,
        rays,
        positions,
        row_ptr,
        cols,
        values,
        sky: Some(sky),
    })
}

/// Where a bake's probes are, before any gather.
#[derive(Debug, Clone, PartialEq)]
pub struct Placed {
    pub spacing: f32,
    pub rays: u32,
    pub positions: Vec<[f32; 3]>,
}

impl Placed {
    /// Gather rows: six a probe.
    pub fn gather_rows(&self) -> usize {
        self.positions.len() * DIRECTIONS
    }
}

/// The probes' positions over `layout`'s grid: every shard of a bake places them all, alike.
pub fn place_probes(
    layout: &PatchLayout,
    occupied: &[u64],
    scene: &SurfaceScene,
    options: &ProbeOptions,
    seed: u64,
) -> Result<Placed, ProbeError> {
    let spacing = options
        .spacing
        .unwrap_or(layout.voxel_size * DEFAULT_SPACING_VOXELS);
    Ok(Placed {
        spacing,
        rays: options.rays,
        positions: place(layout, occupied, scene, spacing, seed)?,
    })
}

/// Gather rows `range` (`6 · probe + direction`) of the probes `placed`. A row depends only on
/// its index, the position and the seed, so rows gathered in parts join into the rows gathered
/// at once. `progress` counts probes whose last direction is among the rows.
pub fn gather_rows(
    scene: &SurfaceScene,
    placed: Placed,
    range: Range<usize>,
    seed: u64,
    progress: &(dyn Fn(u64) + Sync),
) -> ProbeRows {
    let rows: Vec<GatherRow> = range
        .clone()
        .into_par_iter()
        .map(|r| {
            let row = gather(
                scene,
                Vec3::from(placed.positions[r / DIRECTIONS]),
                r,
                placed.rays,
                seed,
            );
            if r % DIRECTIONS == DIRECTIONS - 1 {
                progress(1);
            }
            row
        })
        .collect();
    let mut out = ProbeRows {
        spacing: placed.spacing,
        rays: placed.rays,
        positions: placed.positions,
        range,
        row_ptr: Vec::with_capacity(rows.len() + 1),
        cols: Vec::new(),
        values: Vec::new(),
        sky: SkyVisibility {
            rows: Vec::with_capacity(rows.len()),
        },
    };
    out.row_ptr.push(0);
    for (row, view) in rows {
        for (c, v) in row {
            out.cols.push(c);
            out.values.push(v);
        }
        out.row_ptr.push(out.cols.len() as u32);
        out.sky.rows.push(view);
    }
    out
}

/// Grid points over the layout's box at `spacing`, centred in it, that are probes.
fn place(
    layout: &PatchLayout,
    occupied: &[u64],
    scene: &SurfaceScene,
    spacing: f32,
    seed: u64,
) -> Result<Vec<[f32; 3]>, ProbeError> {
    let origin = Vec3::from(layout.origin);
    let size = Vec3::from(layout.dims.map(|d| d as f32)) * layout.voxel_size;
    let counts = [0, 1, 2].map(|a| ((size[a] / spacing).floor() as u64).max(1));
    let points = counts.iter().fold(1u64, |a, &b| a.saturating_mul(b));
    if points > MAX_GRID_POINTS {
        return Err(ProbeError::TooFine { spacing, points });
    }
    // Centre the grid in the box: the margin left over is split on both sides.
    let first = Vec3::from(
        [0, 1, 2].map(|a| origin[a] + (size[a] - (counts[a] - 1) as f32 * spacing) / 2.0),
    );
    // Capped so that a spacing of many voxels does not make each point scan a large cube: past
    // 8 voxels "near surfaces" means within 8 voxels.
    let reach = (spacing / layout.voxel_size).ceil().clamp(1.0, MAX_REACH) as i64;
    let kept: Vec<[f32; 3]> = (0..points)
        .into_par_iter()
        .filter_map(|i| {
            let g = [
                i % counts[0],
                (i / counts[0]) % counts[1],
                i / (counts[0] * counts[1]),
            ];
            let p = first + Vec3::from(g.map(|v| v as f32)) * spacing;
            let cell = voxel_of(layout, p)?;
            if is_occupied(layout, occupied, cell) || !near_surface(layout, occupied, cell, reach) {
                return None;
            }
            inside(scene, p, i, seed).then_some(p.to_array())
        })
        .collect();
    if kept.len() > MAX_PROBES {
        return Err(ProbeError::TooMany {
            spacing,
            probes: kept.len(),
        });
    }
    Ok(kept)
}

/// The voxel `p` lies in, if it lies in the grid.
fn voxel_of(layout: &PatchLayout, p: Vec3) -> Option<[i64; 3]> {
    let f = (p - Vec3::from(layout.origin)) / layout.voxel_size;
    let c = [0, 1, 2].map(|a| f[a].floor() as i64);
    (0..3)
        .all(|a| c[a] >= 0 && c[a] < i64::from(layout.dims[a]))
        .then_some(c)
}

fn is_occupied(layout: &PatchLayout, occupied: &[u64], c: [i64; 3]) -> bool {
    let d = layout.dims.map(i64::from);
    if (0..3).any(|a| c[a] < 0 || c[a] >= d[a]) {
        return false;
    }
    let key = (c[0] + d[0] * (c[1] + d[1] * c[2])) as u64;
    occupied.binary_search(&key).is_ok()
}

/// Whether an occupied voxel lies within `reach` voxels (along each axis) of `c`.
fn near_surface(layout: &PatchLayout, occupied: &[u64], c: [i64; 3], reach: i64) -> bool {
    (-reach..=reach).any(|dz| {
        (-reach..=reach).any(|dy| {
            (-reach..=reach)
                .any(|dx| is_occupied(layout, occupied, [c[0] + dx, c[1] + dy, c[2] + dz]))
        })
    })
}

/// Whether grid point `p` (number `index`) is inside the scene: of [`TEST_RAYS`] rays spread
/// over the sphere, few meet a back face and not most escape.
fn inside(scene: &SurfaceScene, p: Vec3, index: u64, seed: u64) -> bool {
    let s = crate::formfactor::row_seed(seed ^ 0x5052_4f42_4553, index as usize);
    let (mut back, mut escaped) = (0u32, 0u32);
    for k in 0..TEST_RAYS {
        let [a, b, ..] = sobol_burley::sample_4d(k, TEST_SET, s);
        // Uniform over the sphere.
        let z = 1.0 - 2.0 * a;
        let r = (1.0 - z * z).max(0.0).sqrt();
        let phi = std::f32::consts::TAU * b;
        let dir = Vec3::new(r * phi.cos(), r * phi.sin(), z);
        match scene.free_fate(p, dir) {
            RayFate::BackFace => back += 1,
            RayFate::Escaped => escaped += 1,
            RayFate::Patch(_) | RayFate::Occluder => {}
        }
    }
    let n = TEST_RAYS as f32;
    back as f32 <= MAX_BACK_SHARE * n && escaped as f32 <= MAX_ESCAPED_SHARE * n
}

/// One probe direction's gather: the transport rows its rays met with their shares, and its view
/// of the sky.
type GatherRow = (Vec<(u32, f32)>, [f32; bounce_types::sh::SH_COEFFICIENTS]);

/// Gather row `r` (probe `r / 6`, direction `r % 6`): each transport row met and its share of
/// `rays` cosine-weighted rays about the direction, ascending by row; and the direction's view
/// of the sky from the rays that escaped.
fn gather(scene: &SurfaceScene, p: Vec3, r: usize, rays: u32, seed: u64) -> GatherRow {
    let axis = Face::ALL[r % DIRECTIONS].normal();
    let s = crate::formfactor::row_seed(seed ^ 0x4741_5448_4552, r);
    let mut hits: Vec<u32> = Vec::new();
    let mut sky = SkySum::default();
    for k in 0..rays {
        let [a, b, ..] = sobol_burley::sample_4d(k, GATHER_SET, s);
        let dir = cosine_direction(axis, a, b);
        match scene.free_fate(p, dir) {
            RayFate::Patch(j) => hits.push(j as u32),
            RayFate::Escaped => sky.add(dir),
            RayFate::Occluder | RayFate::BackFace => {}
        }
    }
    hits.sort_unstable();
    let share = 1.0 / rays as f32;
    let mut out: Vec<(u32, f32)> = Vec::new();
    for j in hits {
        match out.last_mut() {
            Some((c, v)) if *c == j => *v += share,
            _ => out.push((j, share)),
        }
    }
    (out, sky.finish(rays))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two() -> Probes {
        Probes {
            spacing: 1.0,
            rays: 4,
            positions: vec![[0.0; 3], [1.0, 0.0, 0.0]],
            row_ptr: vec![0, 2, 2, 2, 2, 2, 2, 3, 3, 3, 3, 3, 3],
            cols: vec![0, 2, 1],
            values: vec![0.25, 0.5, 1.0],
            sky: None,
        }
    }

    #[test]
    fn irradiance_is_the_gather_of_the_exitance() {
        let p = two();
        p.check(3).unwrap();
        let e = p.irradiance(&[[4.0, 0.0, 1.0], [2.0, 2.0, 2.0], [1.0, 8.0, 0.0]]);
        assert_eq!(e.len(), 12);
        assert_eq!(e[0], [1.5, 4.0, 0.25]);
        assert_eq!(e[1], [0.0; 3]);
        assert_eq!(e[6], [2.0, 2.0, 2.0]);
    }

    #[test]
    fn check_refuses_what_a_reader_must_not_trust() {
        assert!(two().check(2).unwrap_err().contains("past the last"));
        let mut p = two();
        p.values[2] = 1.5;
        assert!(p.check(3).unwrap_err().contains("over 1"));
        let mut p = two();
        p.cols.swap(0, 1);
        assert!(p.check(3).unwrap_err().contains("ascending"));
        let mut p = two();
        p.row_ptr.pop();
        assert!(p.check(3).unwrap_err().contains("row offsets"));
        let mut p = two();
        p.positions[1][2] = f32::NAN;
        assert!(p.check(3).unwrap_err().contains("not finite"));
        let mut p = two();
        p.values[0] = 0.0;
        assert!(p.check(3).unwrap_err().contains("not positive"));
    }
}
