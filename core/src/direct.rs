//! Direct irradiance: per patch, the light arriving straight from a [`LightSet`], with shadows.
//!
//! This module owns the per-patch `E_direct` and the initial exitance `B0 = L_e + ρ ⊙ E_direct`
//! (docs/design.md §1) that the transport turns into indirect light. Light validation belongs to
//! [`crate::light`], ray casting to [`crate::rays`].
//!
//! Units and falloff are glTF `KHR_lights_punctual`'s, with `cosθ` taken against the patch's face
//! normal and `L` the unit vector from the surface point towards the light:
//!
//! - point: `E = I · color · cosθ / d² · W(d)`, where `W(d) = clamp(1 − (d/range)⁴, 0, 1)²` when
//!   `range` is set and 1 otherwise;
//! - spot: the point formula times `A = clamp(cd · scale + offset, 0, 1)²`, with
//!   `cd = dot(axis, −L)`, `scale = 1 / max(0.001, cos(inner) − cos(outer))` and
//!   `offset = −cos(outer) · scale`: 0 outside the outer cone, 1 inside the inner one;
//! - directional: `E = I · color · cosθ`, `L = −direction`.
//!
//! A light behind the patch (`cosθ ≤ 0`) contributes nothing and costs no ray.
//!
//! **Sample pattern** (the GPU twin must reproduce it bit for bit in its choice of points):
//! a patch takes `side²` samples, `side = min(⌊√samples⌋, 16)` and at least 1. Sample
//! `k = 0..side²` sits in cell `(i, j) = (k mod side, k div side)` of a `side × side` grid over the
//! patch's quad, at in-plane parameters `((i + ξ₀) / side, (j + ξ₁) / side)` passed to
//! [`Quad::point`], where `ξ_d = jitter(patch, k, d)`:
//!
//! ```text
//! hash(x)            = lowbias32: x ^= x >> 16; x *= 0x7feb352d; x ^= x >> 15;
//!                                 x *= 0x846ca68b; x ^= x >> 16        (u32, wrapping)
//! jitter(patch, k, d) = (f32(hash(hash(patch) ^ (2k + d)) >> 9) + 0.5) · 2⁻²³   ∈ (0, 1)
//! ```
//!
//! Each sample casts one shadow ray per light that reaches it, so shadow edges come out
//! fractional; `E_direct` is the mean over the samples of the sum over the lights, accumulated in
//! f32 in sample order, then light order.

use glam::Vec3;
use rayon::prelude::*;

use crate::coherence::{BlockerMemory, RowHints};
use crate::light::{Light, LightSet, unit_vector};
use crate::patch::{Face, PatchLayout, Quad};
use crate::rays::{MAX_GRID_TRACER_CELLS, RayScene, Tracer};
use crate::surface::{SamplePoint, SurfaceData};
use crate::trimesh::TriMesh;
use crate::visibility::{DEFAULT_BUDGET, LightPlace, RowBits, VisibilityCache};

/// Samples per patch unless asked otherwise: a 4 × 4 grid.
pub const DEFAULT_SAMPLES: u32 = 16;
/// The largest grid side: 256 samples per patch.
pub const MAX_SAMPLES_SIDE: u32 = 16;

/// What shadow rays are traced against.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShadowSource {
    /// The scene's original triangles (surface geometry): what the reference traces too.
    Triangles,
    /// The occupied voxels of the bake: every solid blocks light.
    Occupancy,
    /// Only the patch quads, for a baked file without occupancy: light leaks through solids
    /// whose faces are not patches (occluders, backs of one-sided walls).
    PatchesOnly,
}

/// The geometry that shadow rays are traced against, built once per scene.
pub struct ShadowScene {
    inner: Shadows,
}

enum Shadows {
    Voxels {
        rays: RayScene,
        source: ShadowSource,
    },
    Surface {
        mesh: TriMesh,
        surface: SurfaceData,
        visibility: VisibilityCache,
        blockers: BlockerMemory,
    },
}

impl ShadowScene {
    /// The scene of a surface-geometry bake: shadow rays from its stored sample points against
    /// its triangles (a BVH).
    pub fn surface(surface: &SurfaceData) -> ShadowScene {
        let mesh = surface.mesh();
        ShadowScene {
            inner: Shadows::Surface {
                visibility: VisibilityCache::new(DEFAULT_BUDGET),
                blockers: BlockerMemory::new(DEFAULT_BUDGET),
                mesh,
                surface: surface.clone(),
            },
        }
    }

    /// Sets how many bytes of shadow-ray answers a surface scene keeps from one light set to
    /// the next ([`crate::visibility`]; 0 keeps none, so every ray is traced every time), and
    /// of the last set's blockers ([`crate::coherence`]; 0 keeps none, so every ray the shadow
    /// cache misses walks the tree), and forgets what it kept. The values are the same bits at
    /// any budget, only their cost changes. No effect on a voxel-face scene.
    pub fn set_visibility_budget(&mut self, bytes: usize) {
        if let Shadows::Surface {
            visibility,
            blockers,
            ..
        } = &mut self.inner
        {
            visibility.set_budget(bytes);
            blockers.set_budget(bytes);
        }
    }

    /// Forgets the shadow-ray answers and blockers kept from earlier light sets, keeping their
    /// budgets: the next set costs what a first one does (`bounce bench direct` times a light's
    /// first set after this). The values are the same bits either way.
    pub fn forget_kept(&mut self) {
        if let Shadows::Surface {
            visibility,
            blockers,
            ..
        } = &mut self.inner
        {
            visibility.set_budget(visibility.budget());
            blockers.set_budget(blockers.budget());
        }
    }

    /// The bytes of answers the scene may keep (0 on a voxel-face scene).
    pub fn visibility_budget(&self) -> usize {
        match &self.inner {
            Shadows::Surface { visibility, .. } => visibility.budget(),
            Shadows::Voxels { .. } => 0,
        }
    }

    /// How many light places' answers the scene keeps now (0 on a voxel-face scene).
    pub fn visibility_kept(&self) -> usize {
        match &self.inner {
            Shadows::Surface { visibility, .. } => visibility.kept(),
            Shadows::Voxels { .. } => 0,
        }
    }

    /// How many lights' blockers the scene keeps from its last light set, for the next to
    /// take hints from (0 on a voxel-face scene).
    pub fn blockers_kept(&self) -> usize {
        match &self.inner {
            Shadows::Surface { blockers, .. } => blockers.kept(),
            Shadows::Voxels { .. } => 0,
        }
    }

    /// The shadow geometry of a baked file: its triangles when it has surface geometry, else
    /// its occupancy (or, lacking that, its patches).
    pub fn of_baked(baked: &crate::format::Baked) -> ShadowScene {
        match &baked.surface {
            Some(surface) => ShadowScene::surface(surface),
            None => ShadowScene::new(baked.transport_layout(), baked.occupancy.as_deref()),
        }
    }

    /// The scene of `layout`, blocked by `occupancy` (ascending linear voxel indices, as
    /// [`crate::voxel::Voxelization::occupied`] and [`crate::format::Baked::occupancy`] hold
    /// them) where given, else by the patch quads alone (see [`ShadowScene::source`]). Indices
    /// outside the grid are ignored.
    pub fn new(layout: &PatchLayout, occupancy: Option<&[u64]>) -> ShadowScene {
        ShadowScene::with_tracer(layout, occupancy, Tracer::Grid)
    }

    /// As [`ShadowScene::new`], asking for `tracer` where there is occupancy (the grid tracer
    /// falls back to the BVH for grids too large for it; [`ShadowScene::tracer`] says which).
    /// Both give the same shadows but for rays through exact voxel edges and corners.
    pub fn with_tracer(
        layout: &PatchLayout,
        occupancy: Option<&[u64]>,
        tracer: Tracer,
    ) -> ShadowScene {
        match occupancy {
            Some(occupied) => {
                let cells = layout.dims.iter().map(|&d| u64::from(d)).product::<u64>();
                // The BVH needs the solids' faces as quads; the grid tracer reads the occupancy
                // directly.
                let occluders = if tracer == Tracer::Bvh || cells > MAX_GRID_TRACER_CELLS {
                    exposed_non_patch_faces(layout, occupied)
                } else {
                    Vec::new()
                };
                ShadowScene {
                    inner: Shadows::Voxels {
                        rays: RayScene::voxels(layout, occupied, &occluders, tracer),
                        source: ShadowSource::Occupancy,
                    },
                }
            }
            None => ShadowScene {
                inner: Shadows::Voxels {
                    rays: RayScene::new(&layout.quads(), &[]),
                    source: ShadowSource::PatchesOnly,
                },
            },
        }
    }

    /// Whether shadows come from the triangles, the occupancy or, lacking both, the patches.
    pub fn source(&self) -> ShadowSource {
        match &self.inner {
            Shadows::Voxels { source, .. } => *source,
            Shadows::Surface { .. } => ShadowSource::Triangles,
        }
    }

    /// The tracer the rays go through.
    pub fn tracer(&self) -> Tracer {
        match &self.inner {
            Shadows::Voxels { rays, .. } => rays.tracer(),
            Shadows::Surface { .. } => Tracer::Bvh,
        }
    }

    pub fn patch_count(&self) -> usize {
        match &self.inner {
            Shadows::Voxels { rays, .. } => rays.patch_count(),
            Shadows::Surface { surface, .. } => {
                surface.points.len() / (surface.per_patch.max(1) as usize)
            }
        }
    }

    /// Whether the segment from `origin` on patch `from` along unit `dir` is blocked before
    /// `max_t` (infinite: before leaving the scene).
    pub fn occluded(&self, from: usize, origin: Vec3, dir: Vec3, max_t: f32) -> bool {
        match &self.inner {
            Shadows::Voxels { rays, .. } => rays.occluded(from, origin, dir, max_t),
            Shadows::Surface { mesh, .. } => mesh.occluded(origin, dir, max_t),
        }
    }
}

/// Faces of occupied voxels that look into empty space (or out of the grid) and are not patches.
fn exposed_non_patch_faces(layout: &PatchLayout, occupied: &[u64]) -> Vec<Quad> {
    let dims = layout.dims.map(u64::from);
    let cells = dims.iter().product::<u64>();
    let patch_faces: std::collections::HashSet<([u32; 3], Face)> =
        layout.patches.iter().map(|p| (p.voxel, p.face)).collect();
    let is_occupied = |c: [u64; 3]| {
        occupied
            .binary_search(&(c[0] + dims[0] * (c[1] + dims[1] * c[2])))
            .is_ok()
    };
    let mut quads = Vec::new();
    for &k in occupied.iter().filter(|&&k| k < cells) {
        let c = [k % dims[0], k / dims[0] % dims[1], k / (dims[0] * dims[1])];
        // Below the dims, which are u32.
        let voxel = c.map(|v| v as u32);
        for face in Face::ALL {
            let a = face.axis();
            let mut nb = c;
            let inside = if face.sign() > 0.0 {
                nb[a] += 1;
                nb[a] < dims[a]
            } else if nb[a] > 0 {
                nb[a] -= 1;
                true
            } else {
                false
            };
            if (!inside || !is_occupied(nb)) && !patch_faces.contains(&(voxel, face)) {
                quads.push(layout.face_quad(voxel, face));
            }
        }
    }
    quads
}

/// A light reduced to what the per-sample formula needs, in the form a GPU buffer would hold.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PreparedLight {
    pub kind: LightKind,
    /// Point and spot: the light's position.
    pub position: Vec3,
    /// Directional and spot: the unit direction light travels in.
    pub axis: Vec3,
    /// `intensity · color`.
    pub radiant: Vec3,
    /// `1 / range`, 0 for no range.
    pub inv_range: f32,
    /// Spot: `scale` and `offset` of the angular attenuation (see the module doc).
    pub angle_scale: f32,
    pub angle_offset: f32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LightKind {
    Directional,
    Point,
    Spot,
}

impl PreparedLight {
    /// Where its shadow rays run: what their answers depend on besides the sample points.
    pub fn place(&self) -> LightPlace {
        match self.kind {
            LightKind::Directional => LightPlace::Beam(self.axis),
            LightKind::Point | LightKind::Spot => LightPlace::Point(self.position),
        }
    }

    /// `None` for a light that cannot light anything: one that fails validation (so no
    /// non-finite value reaches the sums) or has zero intensity or colour; and for the sky, which
    /// is no punctual light: it reaches a row through the row's baked sky view
    /// (`crate::sky::SkyVisibility::irradiance`), not a shadow ray per sample.
    pub fn new(light: &Light) -> Option<PreparedLight> {
        light.validate().ok()?;
        let (kind, position, axis, color, intensity, range, cones) = match *light {
            Light::Directional {
                direction,
                color,
                intensity,
                ..
            } => (
                LightKind::Directional,
                Vec3::ZERO,
                unit_vector(direction)?,
                color,
                intensity,
                None,
                None,
            ),
            Light::Point {
                position,
                color,
                intensity,
                range,
                ..
            } => (
                LightKind::Point,
                Vec3::from(position),
                Vec3::ZERO,
                color,
                intensity,
                range,
                None,
            ),
            Light::Spot {
                position,
                direction,
                color,
                intensity,
                range,
                inner_cone_angle,
                outer_cone_angle,
                ..
            } => (
                LightKind::Spot,
                Vec3::from(position),
                unit_vector(direction)?,
                color,
                intensity,
                range,
                Some((inner_cone_angle, outer_cone_angle)),
            ),
            Light::Sky { .. } | Light::Emissive { .. } => return None,
        };
        let radiant = Vec3::from(color) * intensity;
        if radiant.max_element() <= 0.0 {
            return None;
        }
        let (angle_scale, angle_offset) = match cones {
            Some((inner, outer)) => {
                let scale = 1.0 / (inner.cos() - outer.cos()).max(0.001);
                (scale, -outer.cos() * scale)
            }
            None => (0.0, 0.0),
        };
        Some(PreparedLight {
            kind,
            position,
            axis,
            radiant,
            inv_range: range.map_or(0.0, |r| 1.0 / r),
            angle_scale,
            angle_offset,
        })
    }
}

/// What one light delivers to one surface point, before visibility.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LightSample {
    /// Unit vector from the point towards the light: the shadow ray's direction.
    pub dir: Vec3,
    /// How far the shadow ray must get unblocked: the light's distance, infinite for a
    /// directional light.
    pub distance: f32,
    /// Irradiance if nothing blocks the ray.
    pub irradiance: Vec3,
}

/// The glTF range window `clamp(1 − (d/range)⁴, 0, 1)²`; 1 when `inv_range` is 0 (no range).
#[inline]
pub fn range_window(distance: f32, inv_range: f32) -> f32 {
    let x = distance * inv_range;
    let w = (1.0 - x * x * x * x).clamp(0.0, 1.0);
    w * w
}

/// glTF's smooth spot attenuation for `cd`, the cosine between the spot axis and the direction
/// from the light to the point.
#[inline]
pub fn spot_attenuation(cd: f32, angle_scale: f32, angle_offset: f32) -> f32 {
    let a = (cd * angle_scale + angle_offset).clamp(0.0, 1.0);
    a * a
}

/// What `light` delivers at point `p` with unit normal `n`, if anything: `None` when the light
/// is behind the surface, out of range or outside its cone (no ray needed then).
#[inline]
pub fn light_sample(light: &PreparedLight, p: Vec3, n: Vec3) -> Option<LightSample> {
    match reach(light, p, n) {
        Reach::Lit(s) => Some(s),
        Reach::Away | Reach::Dark => None,
    }
}

/// Whether a light reaches a point, and why not: a shadow-ray answer kept for a light's place
/// ([`crate::visibility`]) may stand for "away", which no other light at that place changes,
/// but not for "dark", which another range or cone does.
enum Reach {
    /// It would, if its shadow ray is open.
    Lit(LightSample),
    /// The light is behind the surface or on the point: so is any light at that place.
    Away,
    /// Out of the light's range or cone.
    Dark,
}

/// [`light_sample`], saying why not.
#[inline(always)]
fn reach(light: &PreparedLight, p: Vec3, n: Vec3) -> Reach {
    let (dir, distance, scale) = match light.kind {
        LightKind::Directional => (-light.axis, f32::INFINITY, 1.0),
        LightKind::Point | LightKind::Spot => {
            let to = light.position - p;
            let d2 = to.length_squared();
            let d = d2.sqrt();
            if !(d > 0.0 && d.is_finite()) {
                // The light sits on the point: no direction to take a cosine with.
                return Reach::Away;
            }
            let dir = to / d;
            let mut scale = range_window(d, light.inv_range) / d2;
            if light.kind == LightKind::Spot {
                scale *=
                    spot_attenuation(light.axis.dot(-dir), light.angle_scale, light.angle_offset);
            }
            (dir, d, scale)
        }
    };
    let cos = n.dot(dir);
    // Zero factors end here, before they can meet an infinite product.
    if cos.is_nan() || cos <= 0.0 {
        return Reach::Away;
    }
    if scale.is_nan() || scale <= 0.0 {
        return Reach::Dark;
    }
    Reach::Lit(LightSample {
        dir,
        distance,
        irradiance: light.radiant * (cos * scale),
    })
}

/// How far a shadow ray towards a point or spot light must get unblocked: up to where it comes
/// within one voxel of the light (enters the cube of half-width `size` centred on it), not to the
/// light itself. Voxels are coarse: a light placed in free space a little off a wall, or inside a
/// thin lamp shade, often sits in a voxel the wall made occupied (or on the boundary of one), and
/// would otherwise be shadowed from everything. That cube holds every voxel that contains the
/// light whatever its place in the grid. The price: such a light also reaches through up to one
/// voxel of solid around it. A directional light (infinite `distance`) is unchanged.
///
/// The result is `min(distance, max(t − size/1000, 0))` with `t` the entry distance of the ray
/// `p + t·dir` into that cube (the slab method); the margin keeps the grid walk's own rounding of
/// boundary distances from counting a voxel the cube covers.
#[inline]
pub fn shadow_length(p: Vec3, dir: Vec3, distance: f32, light: Vec3, size: f32) -> f32 {
    if !distance.is_finite() {
        return distance;
    }
    let (lo, hi) = (light - Vec3::splat(size), light + Vec3::splat(size));
    let mut enter = 0.0f32;
    for a in 0..3 {
        if dir[a] != 0.0 {
            let (t0, t1) = ((lo[a] - p[a]) / dir[a], (hi[a] - p[a]) / dir[a]);
            enter = enter.max(t0.min(t1));
        }
    }
    distance.min((enter - size * 1e-3).max(0.0))
}

/// lowbias32 (C. Wellons): a cheap u32 hash with good avalanche, written the same in WGSL.
#[inline]
pub fn hash_u32(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^= x >> 16;
    x
}

/// The jitter of coordinate `dim` (0 or 1) of sample `k` on `patch`, strictly inside (0, 1).
#[inline]
pub fn jitter(patch: u32, k: u32, dim: u32) -> f32 {
    let h = hash_u32(hash_u32(patch) ^ k.wrapping_mul(2).wrapping_add(dim));
    // 23 bits plus a half fit f32's 24-bit significand exactly, so the result is never 0 or 1.
    ((h >> 9) as f32 + 0.5) * (1.0 / (1u32 << 23) as f32)
}

/// The grid side used for a requested sample count.
pub fn samples_side(samples: u32) -> u32 {
    samples.isqrt().clamp(1, MAX_SAMPLES_SIDE)
}

/// In-plane parameters in (0, 1)² of sample `k` of a `side × side` grid on `patch`.
#[inline]
pub fn sample_uv(patch: u32, k: u32, side: u32) -> [f32; 2] {
    let s = side as f32;
    let (i, j) = (k % side, k / side);
    [
        (i as f32 + jitter(patch, k, 0)) / s,
        (j as f32 + jitter(patch, k, 1)) / s,
    ]
}

/// Direct irradiance (linear RGB) on every patch of `layout` from `lights`, shadowed by `scene`
/// (built from the same layout), with about `samples` samples per patch (see the module doc for
/// the pattern). Lights that fail validation are skipped. The result is the same bits whatever
/// the thread count: each patch is summed by one thread in a fixed order.
///
/// # Panics
/// If `scene` was built from a layout with a different patch count: a caller's bug.
pub fn direct_irradiance(
    scene: &ShadowScene,
    layout: &PatchLayout,
    lights: &LightSet,
    samples: u32,
) -> Vec<[f32; 3]> {
    assert_eq!(
        scene.patch_count(),
        layout.len(),
        "shadow scene and layout disagree on the patch count"
    );
    let prepared: Vec<PreparedLight> = lights
        .lights
        .iter()
        .filter_map(PreparedLight::new)
        .collect();
    if let Shadows::Surface {
        mesh,
        surface,
        visibility,
        blockers,
    } = &scene.inner
    {
        // Only the samples spread by area make the mean; landing samples serve the near field.
        let count = surface.mean_count(samples.clamp(1, surface.per_patch) as usize);
        let places = places(&prepared);
        let per_row = surface.per_patch as usize;
        let mut fresh = visibility.begin(&places, layout.len(), per_row);
        let (words, stride) = (fresh.tracked_words(), fresh.stride());
        let (hints, mut ids) = blockers.begin(&places, layout.len(), per_row);
        let shadows = Shadowing { mesh };
        let mean = fresh
            .bits
            .par_chunks_mut(stride)
            .zip(ids.par_chunks_mut(hints.stride()))
            .enumerate()
            .map_init(
                || (ShadowCache::new(prepared.len()), Vec::new()),
                |(cache, blocked), (i, (chunk, row_ids))| {
                    shadows.mean_irradiance(
                        &surface.samples(i)[..count],
                        &prepared,
                        cache,
                        &mut RowBits::new(words, chunk),
                        &mut hints.row(i, row_ids),
                        blocked,
                    )
                },
            )
            .collect();
        visibility.keep(&places, fresh);
        blockers.keep(hints, ids);
        return mean;
    }
    let side = samples_side(samples);
    (0..layout.len())
        .into_par_iter()
        .map(|i| patch_irradiance(scene, layout, i, &prepared, side))
        .collect()
}

/// How far short of a point light a shadow ray stops, relative to the light's distance: a light
/// placed exactly on a surface (a bulb on its fixture) is not shadowed by that surface. Far less
/// than any voxel: no light reaches through a wall.
pub const SHADOW_END: f32 = 1.0 - 1e-5;

/// One surface patch's mean over its sample points, each shadow ray traced against the
/// triangles from the stored (already offset) point: each sample's lights summed in light order,
/// then the samples' sums in sample order, as the GPU twin (`direct_surface.wgsl`) does. The
/// mean is the mean of [`sample_irradiance`]'s values, so the near-field correction
/// ([`crate::nearfield`]) sees each element's samples sum to their mean.
pub fn surface_irradiance(
    mesh: &TriMesh,
    samples: &[SamplePoint],
    lights: &[PreparedLight],
    cache: &mut ShadowCache,
) -> [f32; 3] {
    Shadowing { mesh }.mean_irradiance(
        samples,
        lights,
        cache,
        &mut RowBits::none(),
        &mut RowHints::none(),
        &mut Vec::new(),
    )
}

/// Where each light's shadow rays run, for the answers kept of them.
fn places(lights: &[PreparedLight]) -> Vec<LightPlace> {
    lights.iter().map(PreparedLight::place).collect()
}

/// What a surface scene's shadow rays are answered from: the answers a row's [`RowBits`] hold
/// from an earlier light set at a light's place, else the triangles.
#[derive(Clone, Copy)]
struct Shadowing<'a> {
    mesh: &'a TriMesh,
}

impl Shadowing<'_> {
    /// [`surface_irradiance`] over one row's samples, with the row's kept answers.
    fn mean_irradiance(
        &self,
        samples: &[SamplePoint],
        lights: &[PreparedLight],
        cache: &mut ShadowCache,
        bits: &mut RowBits,
        hints: &mut RowHints,
        blocked: &mut Vec<bool>,
    ) -> [f32; 3] {
        if lights.is_empty() || samples.is_empty() {
            return [0.0; 3];
        }
        let pilots = pilots_apply(samples.len() as u32);
        if pilots {
            self.pilot_blocked(samples, lights, cache, bits, hints, blocked);
        }
        let mut sum = Vec3::ZERO;
        for (k, s) in samples.iter().enumerate() {
            let rule: &[bool] = if pilots && k % PILOT_STRIDE != 0 {
                blocked
            } else {
                &[]
            };
            sum += Vec3::from(self.point_irradiance(s, k, lights, cache, bits, hints, rule));
        }
        mean_of(sum, samples.len())
    }

    /// The irradiance of a row's sample `k`, `s`: its lights summed in light order, kept
    /// finite. A light for which `blocked` holds true (the pilot rule's verdict) adds nothing.
    #[allow(clippy::too_many_arguments)]
    fn point_irradiance(
        &self,
        s: &SamplePoint,
        k: usize,
        lights: &[PreparedLight],
        cache: &mut ShadowCache,
        bits: &mut RowBits,
        hints: &mut RowHints,
        blocked: &[bool],
    ) -> [f32; 3] {
        let (p, n) = (Vec3::from(s.position), Vec3::from(s.normal));
        let mut e = Vec3::ZERO;
        for (j, (light, recent)) in lights.iter().zip(cache.0.iter_mut()).enumerate() {
            // Taken as blocked by the row's pilots ([`pilot_blocked`]) even where an answer
            // is known: the value must not depend on which sets came before.
            if blocked.get(j) == Some(&true) {
                continue;
            }
            match bits.known(j, k) {
                // Blocked, or facing away from the place: nothing, whatever the light.
                Some(false) => {}
                Some(true) => {
                    if let Some(l) = light_sample(light, p, n) {
                        e += l.irradiance;
                    }
                }
                None => match reach(light, p, n) {
                    Reach::Lit(l) => {
                        let open =
                            self.trace(p, l.dir, l.distance * SHADOW_END, j, k, recent, hints);
                        if open {
                            e += l.irradiance;
                        }
                        bits.record(j, k, open);
                    }
                    Reach::Away => bits.record(j, k, false),
                    Reach::Dark => {}
                },
            }
        }
        e.min(Vec3::splat(f32::MAX)).to_array()
    }
}

impl Shadowing<'_> {
    /// Per light, whether the pilot rule ([`pilots_apply`]) takes the row's other samples
    /// as blocked: some pilot (every [`PILOT_STRIDE`]-th sample, from the first) faces the
    /// light and none is reached by it. Each pilot's answer is kept as any ray's is, so the
    /// row's own pass reads it instead of tracing again.
    fn pilot_blocked(
        &self,
        row: &[SamplePoint],
        lights: &[PreparedLight],
        cache: &mut ShadowCache,
        bits: &mut RowBits,
        hints: &mut RowHints,
        blocked: &mut Vec<bool>,
    ) {
        blocked.clear();
        for (j, (light, recent)) in lights.iter().zip(cache.0.iter_mut()).enumerate() {
            let mut faced = false;
            let mut reached = false;
            for (k, s) in row.iter().enumerate().step_by(PILOT_STRIDE) {
                let (p, n) = (Vec3::from(s.position), Vec3::from(s.normal));
                match reach(light, p, n) {
                    Reach::Lit(l) => {
                        faced = true;
                        let open = match bits.known(j, k) {
                            Some(open) => open,
                            None => {
                                let open = self.trace(
                                    p,
                                    l.dir,
                                    l.distance * SHADOW_END,
                                    j,
                                    k,
                                    recent,
                                    hints,
                                );
                                bits.record(j, k, open);
                                open
                            }
                        };
                        if open {
                            // Every other sample is traced; the pilots left are on the
                            // row's own pass.
                            reached = true;
                            break;
                        }
                    }
                    Reach::Away => bits.record(j, k, false),
                    Reach::Dark => {}
                }
            }
            blocked.push(faced && !reached);
        }
    }

    /// Whether sample `k`'s ray from `p` towards light `j` is open, traced: the last set's
    /// blocker first (where the light moved a little it blocks again, and saves the walk the
    /// shadow cache would miss), then the cache and the tree. Out of line: it costs a ray
    /// either way, and the known answers' loop around it stays small (inlined, it made a light
    /// that stays put 15% slower).
    #[inline(never)]
    #[allow(clippy::too_many_arguments)]
    fn trace(
        &self,
        p: Vec3,
        dir: Vec3,
        t_max: f32,
        j: usize,
        k: usize,
        recent: &mut Vec<u32>,
        hints: &mut RowHints,
    ) -> bool {
        let blocker = match hints.hint(j, k) {
            Some(h) if self.mesh.blocks(h, p, dir, t_max) => Some(h),
            _ => self.mesh.blocker(p, dir, t_max, recent),
        };
        if let Some(b) = blocker {
            remember(recent, b);
        }
        hints.record(j, k, blocker);
        blocker.is_none()
    }
}

/// Direct irradiance at each of `samples` (the values [`surface_irradiance`] averages).
pub fn sample_irradiance(
    mesh: &TriMesh,
    samples: &[SamplePoint],
    lights: &[PreparedLight],
    cache: &mut ShadowCache,
) -> Vec<[f32; 3]> {
    let shadows = Shadowing { mesh };
    samples
        .iter()
        .enumerate()
        .map(|(k, s)| {
            shadows.point_irradiance(
                s,
                k,
                lights,
                cache,
                &mut RowBits::none(),
                &mut RowHints::none(),
                &[],
            )
        })
        .collect()
}

/// Per light, the last few triangles that blocked a shadow ray, most recent first: the next
/// ray towards that light tries them before the tree ([`TriMesh::blocker`]). Rays from one
/// element's samples, and from the neighbouring elements a thread takes next, are mostly
/// blocked by the same few triangles. An answer never depends on what the cache holds, only
/// its cost does; one cache serves one light set on one thread.
pub struct ShadowCache(Vec<Vec<u32>>);

/// Blockers remembered per light. On `pandora` (60,694 triangles) under the corridor light,
/// about 95% of the shadow rays are blocked; per element alone, one remembered triangle caught
/// a third of them, four 60%, eight 64%, and kept across a thread's elements eight caught 79%.
const REMEMBERED: usize = 8;

impl ShadowCache {
    /// An empty cache for a light set of `lights` prepared lights.
    pub fn new(lights: usize) -> ShadowCache {
        ShadowCache(vec![Vec::with_capacity(REMEMBERED); lights])
    }
}

/// Puts `b` first in `recent`, keeping at most [`REMEMBERED`].
fn remember(recent: &mut Vec<u32>, b: u32) {
    match recent.iter().position(|&r| r == b) {
        Some(at) => recent[..=at].rotate_right(1),
        None => {
            if recent.len() == REMEMBERED {
                recent.pop();
            }
            recent.insert(0, b);
        }
    }
}

/// Every how many samples of a row a pilot stands: samples `0, 4, 8, …` ([`pilots_apply`]).
pub const PILOT_STRIDE: usize = 4;

/// Whether direct light over rows of `averaged` samples spread by area follows the pilot rule:
/// towards each light a row traces its pilots first (every [`PILOT_STRIDE`]-th of those
/// samples), and where some pilot faces the light and none is reached by it, the row's other
/// samples (its landing samples too) are taken as blocked without a ray. A row lit anywhere
/// traces every ray: an open row's other rays find the small shadows its pilots miss. Only
/// rows of more than 32 samples by area, so the default's 24 trace every ray as before. On
/// `pandora` at 128 samples (96 by area, so 24 pilots) the rule moved the method error from
/// 9.56% to 9.72% under a sun and from 7.62% to 7.64% under the corridor light, and cut the
/// CPU's direct light for a moving light by about a third (README, "The pilot rule"). The
/// GPU's `shadow_pilots` pass follows the same rule.
pub fn pilots_apply(averaged: u32) -> bool {
    averaged > 32
}

/// The mean of per-sample irradiance summed in sample order, kept finite for the encoders.
fn mean_of(sum: Vec3, count: usize) -> [f32; 3] {
    (sum / count as f32).min(Vec3::splat(f32::MAX)).to_array()
}

/// Direct light of a surface scene on every transport row of `layout` and at every one of its
/// first `samples` sample points (clamped to what the file stores), for the near-field
/// correction: per row the mean (as [`direct_irradiance`] gives it) and per row its samples'
/// values (`count` a row). `None` for a voxel-face scene, which has no sample points.
pub fn direct_with_samples(
    scene: &ShadowScene,
    layout: &PatchLayout,
    lights: &LightSet,
    samples: u32,
) -> Option<SampledDirect> {
    let Shadows::Surface {
        mesh,
        surface,
        visibility,
        blockers,
    } = &scene.inner
    else {
        return None;
    };
    assert_eq!(
        surface.points.len() / surface.per_patch.max(1) as usize,
        layout.len(),
        "shadow scene and layout disagree on the row count"
    );
    let prepared: Vec<PreparedLight> = lights
        .lights
        .iter()
        .filter_map(PreparedLight::new)
        .collect();
    // A file stores at least one sample a row; a hand-built `SurfaceData` may store none, and
    // its rows are then unlit.
    let count = samples.max(1).min(surface.per_patch) as usize;
    let averaged = surface.mean_count(count);
    let n = layout.len();
    let mut out = SampledDirect {
        count: count as u32,
        mean: vec![[0.0; 3]; n],
        samples: vec![[0.0; 3]; n * count],
    };
    if prepared.is_empty() || count == 0 {
        return Some(out);
    }
    let places = places(&prepared);
    let per_row = surface.per_patch as usize;
    let mut fresh = visibility.begin(&places, n, per_row);
    let (words, stride) = (fresh.tracked_words(), fresh.stride());
    let (hints, mut ids) = blockers.begin(&places, n, per_row);
    let shadows = Shadowing { mesh };
    // The pilots are among the samples of the mean, so the mean is what `direct_irradiance`
    // gives; their answer serves the landing samples too.
    let pilots = pilots_apply(averaged as u32);
    // Written in place, a row's samples and its mean by one thread: no allocation per row, and
    // the same values in the same order as before (the cache and the kept answers change what
    // a ray costs, never its answer).
    out.samples
        .par_chunks_mut(count)
        .zip(out.mean.par_iter_mut())
        .zip(fresh.bits.par_chunks_mut(stride))
        .zip(ids.par_chunks_mut(hints.stride()))
        .enumerate()
        .for_each_init(
            || (ShadowCache::new(prepared.len()), Vec::new()),
            |(cache, blocked), (i, (((values, mean), chunk), row_ids))| {
                let mut bits = RowBits::new(words, chunk);
                let mut hints = hints.row(i, row_ids);
                let mut sum = Vec3::ZERO;
                let row = &surface.samples(i)[..count];
                if pilots {
                    shadows.pilot_blocked(
                        &row[..averaged],
                        &prepared,
                        cache,
                        &mut bits,
                        &mut hints,
                        blocked,
                    );
                }
                for (k, (v, s)) in values.iter_mut().zip(row).enumerate() {
                    let pilot = k < averaged && k % PILOT_STRIDE == 0;
                    let rule: &[bool] = if pilots && !pilot { blocked } else { &[] };
                    *v = shadows
                        .point_irradiance(s, k, &prepared, cache, &mut bits, &mut hints, rule);
                    if k < averaged {
                        sum += Vec3::from(*v);
                    }
                }
                *mean = mean_of(sum, averaged);
            },
        );
    visibility.keep(&places, fresh);
    blockers.keep(hints, ids);
    Some(out)
}

/// Direct light per transport row and at each of its sample points ([`direct_with_samples`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SampledDirect {
    /// Sample points used a row.
    pub count: u32,
    /// Per row, the mean of its samples spread by area (`SurfaceData::mean_count`): `E_direct`.
    pub mean: Vec<[f32; 3]>,
    /// Per row, `count` values in sample order.
    pub samples: Vec<[f32; 3]>,
}

/// One patch's mean over its samples.
fn patch_irradiance(
    scene: &ShadowScene,
    layout: &PatchLayout,
    patch: usize,
    lights: &[PreparedLight],
    side: u32,
) -> [f32; 3] {
    if lights.is_empty() {
        return [0.0; 3];
    }
    let quad = layout.quad(patch);
    let n = quad.normal();
    let count = side * side;
    let mut sum = Vec3::ZERO;
    for k in 0..count {
        // Patch indices beyond u32 do not occur (a layout holds at most u32::MAX patches);
        // wrapping would only change the jitter.
        let [u, v] = sample_uv(patch as u32, k, side);
        let p = quad.point(u, v);
        for light in lights {
            if let Some(s) = light_sample(light, p, n)
                && !scene.occluded(
                    patch,
                    p,
                    s.dir,
                    shadow_length(p, s.dir, s.distance, light.position, layout.voxel_size),
                )
            {
                sum += s.irradiance;
            }
        }
    }
    // A sum of very bright lights may overflow; keep the result finite for the encoders.
    (sum / count as f32).min(Vec3::splat(f32::MAX)).to_array()
}

/// Initial exitance `B0 = L_e + ρ ⊙ E_direct` per patch (docs/design.md §1).
///
/// # Panics
/// If `e_direct` does not have one entry per patch: a caller's bug.
pub fn exitance_b0(layout: &PatchLayout, e_direct: &[[f32; 3]]) -> Vec<[f32; 3]> {
    assert_eq!(
        e_direct.len(),
        layout.len(),
        "one direct irradiance per patch"
    );
    layout
        .patches
        .iter()
        .zip(e_direct)
        .map(|(p, e)| std::array::from_fn(|c| p.emission[c] + p.albedo[c] * e[c]))
        .collect()
}

/// `B0` as [`exitance_b0`] gives it, with each patch's emission `emission[i]` in place of the
/// layout's: a light set's emissive changes (`crate::emitter`).
///
/// # Panics
/// If `emission` or `e_direct` does not have one entry per patch: a caller's bug.
pub fn exitance_with(
    layout: &PatchLayout,
    emission: &[[f32; 3]],
    e_direct: &[[f32; 3]],
) -> Vec<[f32; 3]> {
    assert_eq!(emission.len(), layout.len(), "one emission per patch");
    assert_eq!(
        e_direct.len(),
        layout.len(),
        "one direct irradiance per patch"
    );
    layout
        .patches
        .iter()
        .zip(emission.iter().zip(e_direct))
        .map(|(p, (l, e))| std::array::from_fn(|c| l[c] + p.albedo[c] * e[c]))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pinned values, for the GPU twin to check its hash and jitter against.
    #[test]
    fn hash_and_jitter_are_pinned() {
        assert_eq!(hash_u32(0), 0);
        assert_eq!(hash_u32(1), 0x6889_90c0);
        assert_eq!(hash_u32(12345), 2_435_775_735);
        let h = hash_u32(hash_u32(7) ^ 7);
        assert_eq!(jitter(7, 3, 1), ((h >> 9) as f32 + 0.5) / 8_388_608.0);
        assert_eq!(jitter(0, 0, 0), 0.5 / 8_388_608.0);
        for patch in 0..64 {
            for k in 0..64 {
                for d in 0..2 {
                    let j = jitter(patch, k, d);
                    assert!(j > 0.0 && j < 1.0, "{j}");
                }
            }
        }
    }

    #[test]
    fn samples_form_a_stratified_grid() {
        assert_eq!(samples_side(0), 1);
        assert_eq!(samples_side(16), 4);
        assert_eq!(samples_side(24), 4);
        assert_eq!(samples_side(100_000), MAX_SAMPLES_SIDE);
        for k in 0..16 {
            let [u, v] = sample_uv(9, k, 4);
            assert_eq!(((u * 4.0) as u32, (v * 4.0) as u32), (k % 4, k / 4));
        }
    }

    #[test]
    fn falloff_windows() {
        assert_eq!(range_window(5.0, 0.0), 1.0);
        assert_eq!(range_window(2.0, 0.5), 0.0);
        assert_eq!(range_window(3.0, 0.5), 0.0);
        assert!((range_window(1.0, 0.5) - (1.0f32 - 0.0625).powi(2)).abs() < 1e-7);
        let (inner, outer) = (0.3f32, 0.6f32);
        let scale = 1.0 / (inner.cos() - outer.cos());
        let offset = -outer.cos() * scale;
        assert_eq!(spot_attenuation(1.0, scale, offset), 1.0);
        assert_eq!(spot_attenuation(0.29f32.cos(), scale, offset), 1.0);
        assert_eq!(spot_attenuation(0.61f32.cos(), scale, offset), 0.0);
        let mid = spot_attenuation(0.45f32.cos(), scale, offset);
        assert!(mid > 0.0 && mid < 1.0, "{mid}");
    }

    #[test]
    fn light_behind_or_on_the_surface_gives_nothing() {
        let point = PreparedLight::new(&Light::Point {
            position: [0.0, 1.0, 0.0],
            color: [1.0; 3],
            intensity: 4.0,
            range: None,
            name: None,
        })
        .unwrap();
        let s = light_sample(&point, Vec3::ZERO, Vec3::Y).unwrap();
        assert_eq!(s.irradiance, Vec3::splat(4.0));
        assert_eq!(s.distance, 1.0);
        assert_eq!(s.dir, Vec3::Y);
        assert_eq!(light_sample(&point, Vec3::ZERO, Vec3::NEG_Y), None);
        assert_eq!(light_sample(&point, Vec3::Y, Vec3::Y), None);
        let sun = PreparedLight::new(&Light::Directional {
            direction: [0.0, -2.0, 0.0],
            color: [1.0, 0.5, 0.0],
            intensity: 3.0,
            name: None,
        })
        .unwrap();
        let s = light_sample(&sun, Vec3::ZERO, Vec3::Y).unwrap();
        assert_eq!(s.irradiance, Vec3::new(3.0, 1.5, 0.0));
        assert_eq!(s.distance, f32::INFINITY);
        // Invalid and dark lights are dropped before any ray.
        let dark = Light::Directional {
            direction: [0.0, -1.0, 0.0],
            color: [1.0; 3],
            intensity: 0.0,
            name: None,
        };
        assert_eq!(PreparedLight::new(&dark), None);
        let broken = Light::Directional {
            direction: [0.0, f32::NAN, 0.0],
            color: [1.0; 3],
            intensity: 1.0,
            name: None,
        };
        assert_eq!(PreparedLight::new(&broken), None);
    }
}
