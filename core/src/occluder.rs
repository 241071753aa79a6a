//! Occluder maps: shadow rays proved blocked without being traced.
//!
//! This module owns one acceleration of the CPU's direct light ([`crate::direct`]) on a
//! surface-geometry scene. It does not change a value: it only ever answers "blocked", where
//! [`TriMesh::blocker`] would say the same, and every other ray is traced as before. The GPU twin
//! traces every ray and is compared with the CPU as before.
//!
//! Per punctual light of a light set, a map of cells of directions towards the light: six
//! `res × res` faces of a cube around a point or spot light, one grid across a directional
//! light's beam. A cell keeps, of the triangles that cover the **whole** cell (widened by a
//! margin), the least "farthest depth within the cell": the distance from the light for a cube,
//! the height below the sun for a beam. A sample whose shadow ray runs through a cell from
//! deeper than that (by a margin) is in shadow: the segment from the sample to the light lies
//! along one line from the light, so it crosses that triangle well inside its edges and well
//! inside the segment's ends, and the exact ray–triangle test meets it too.
//!
//! What it spares, and what it costs: in a level lit by one lamp most shadow rays are blocked
//! (95% of a corridor light's in `pandora`), many of them by walls that cover whole cells. At
//! the default 128 cells a side the corridor light's map proves 55% of them (78% at 256, 91% at
//! 512), but it takes about as long to build (about 15 ms on one core at 128, front to back
//! through the BVH, a subtree skipped where every cell it could reach holds a nearer triangle
//! or where its triangles are too small to cover a cell) as it spares one light set, because
//! the rays it proves are mostly the cheap ones the shadow cache answers. So a map is built
//! only for a light whose place is asked for a second time, and kept ([`OccluderMaps`]): a light
//! that stays put while others move, or that several light sets share, pays once.
//!
//! The margins, and why they hold in f32 (a wrong "blocked" would be a wrong value):
//! - a cell counts as covered only if a disc of [`EDGE_MARGIN`] cells around it lies inside the
//!   triangle's projection: that is about 10⁻⁴ rad at 256 cells a face, where the ray's own
//!   direction and the texel lookup err by about 10⁻⁷; and a triangle more than
//!   [`MAX_SPAN`] times larger than its distance from a point light is left out, so that margin
//!   stays far above the ray–triangle test's rounding in barycentric terms;
//! - a cell's depth is taken at the corners of the widened cell (depth along a plane is convex
//!   over a convex region, and linear for a beam), and a ray must start deeper than it by
//!   [`DEPTH_MARGIN`] of its length plus [`SCALE_MARGIN`] of the scene's size;
//! - a triangle nearer a point light than [`NEAR_SHARE`] of the scene's size is left out, and a
//!   sample farther from the light than five times the scene's size is traced, so the crossing
//!   is never in the last 10⁻⁵ of the segment that [`crate::direct::SHADOW_END`] leaves
//!   untraced.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

use glam::Vec3;
use rayon::prelude::*;

use crate::trimesh::{MeshNode, MeshTri, TriMesh};

/// The margin around a cell, in cells, that a covering triangle must also cover.
pub const EDGE_MARGIN: f32 = 1.0 / 64.0;
/// Relative margin between a cell's depth and a ray's.
pub const DEPTH_MARGIN: f32 = 1e-4;
/// Absolute margin between a cell's depth and a ray's, as a share of the scene's size.
pub const SCALE_MARGIN: f32 = 1e-5;
/// Nearest a triangle's plane may pass a point light, as a share of the scene's size.
pub const NEAR_SHARE: f32 = 1e-4;
/// Largest a triangle may be against its plane's distance from a point light.
pub const MAX_SPAN: f32 = 100.0;
/// Cells a side of a cube face (a beam grid has about six times as many cells in all) unless
/// asked otherwise.
pub const DEFAULT_RESOLUTION: u32 = 128;
/// Cells a side of a coarse tile, the unit a node's footprint is tested against.
const TILE: u32 = 8;

/// What every map of one mesh starts from: the BVH's nodes, and per node the longest edge of
/// a triangle under it, so a map skips whole subtrees too fine to cover a cell. Built once per
/// scene.
pub struct OccluderTree {
    nodes: Vec<MeshNode>,
    span: Vec<f32>,
}

impl OccluderTree {
    pub fn new(mesh: &TriMesh) -> OccluderTree {
        let nodes = mesh.nodes();
        let tris = mesh.triangles();
        let mut span = vec![0.0f32; nodes.len()];
        // Post order with an explicit stack: a node's span once both children have theirs.
        let mut stack: Vec<(u32, bool)> = if nodes.is_empty() {
            Vec::new()
        } else {
            vec![(0, false)]
        };
        while let Some((at, done)) = stack.pop() {
            let node = &nodes[at as usize];
            if node.prim_count > 0 {
                let first = node.first_index as usize;
                span[at as usize] = tris[first..first + node.prim_count as usize]
                    .iter()
                    .map(|t| {
                        let (e1, e2) = (Vec3::from(t.e1), Vec3::from(t.e2));
                        e1.length().max(e2.length()).max((e2 - e1).length())
                    })
                    .fold(0.0, f32::max);
            } else if done {
                let (a, b) = (node.first_index as usize, node.first_index as usize + 1);
                span[at as usize] = span[a].max(span[b]);
            } else {
                stack.push((at, true));
                stack.push((node.first_index, false));
                stack.push((node.first_index + 1, false));
            }
        }
        OccluderTree { nodes, span }
    }
}

/// What a map is built for: where a light's shadow rays run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LightPlace {
    /// A point or spot light at this position: rays run to it.
    Point(Vec3),
    /// A directional light whose light travels along this unit axis: rays run against it.
    Beam(Vec3),
}

/// A scene's occluder maps: its tree, the resolution maps are built at, and the maps of the
/// lights last asked for. A map depends only on the triangles, the light's place (a point or
/// spot light's position, a directional light's direction) and the resolution, never on its
/// colour, intensity, range or cone, and its answers never change a value: so a light that
/// stays where it was from one light set to the next, or that several sessions share (a sun),
/// reuses its map.
pub struct OccluderMaps {
    tree: OccluderTree,
    res: u32,
    shadow_end: f32,
    recent: Mutex<Recent>,
}

/// The maps kept, and the places of lights seen once without one, oldest first.
#[derive(Default)]
struct Recent {
    maps: VecDeque<(MapKey, Arc<OccluderMap>)>,
    seen: VecDeque<MapKey>,
}

/// What a map is built from besides the mesh.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct MapKey {
    beam: bool,
    /// A point or spot light's position, a directional light's axis, as bits.
    place: [u32; 3],
    res: u32,
}

/// Maps kept per scene: a light set's lights and the last few sets' (about 0.8 MB a map at
/// the default resolution).
pub const KEPT_MAPS: usize = 16;
/// Places of lights seen once kept per scene: two full light sets' worth, so that a set of
/// many lights finds its own from the time before (16 bytes each).
const SEEN_PLACES: usize = 2 * crate::light::MAX_LIGHTS;

impl OccluderMaps {
    /// The maps of `mesh`, built [`DEFAULT_RESOLUTION`] cells a side, for shadow rays
    /// traced up to `shadow_end` of a point light's distance (`crate::direct::SHADOW_END`).
    pub fn new(mesh: &TriMesh, shadow_end: f32) -> OccluderMaps {
        OccluderMaps {
            tree: OccluderTree::new(mesh),
            res: DEFAULT_RESOLUTION,
            shadow_end,
            recent: Mutex::new(Recent::default()),
        }
    }

    /// How many maps are kept now.
    pub fn kept(&self) -> usize {
        self.recent.lock().map_or(0, |r| r.maps.len())
    }

    /// Cells a side of a cube face; 0 builds no map, so every ray is traced.
    pub fn resolution(&self) -> u32 {
        self.res
    }

    pub fn set_resolution(&mut self, res: u32) {
        self.res = res;
        *self.recent.get_mut().unwrap_or_else(|e| e.into_inner()) = Recent::default();
    }

    /// The maps of a light set's lights (where their rays run) over `mesh` (the mesh these
    /// maps were made for), in their order; none at all at resolution 0. A light gets a map the second time
    /// its place is asked for, and keeps it while it is among the last [`KEPT_MAPS`]: on
    /// `pandora` a map costs about what it spares one light set (README, "Occluder maps"),
    /// so a light that moves every set (a lamp dragged across the room) is traced as
    /// without maps, and one that stays put pays once.
    pub fn for_lights(
        &self,
        mesh: &TriMesh,
        lights: &[LightPlace],
    ) -> Vec<Option<Arc<OccluderMap>>> {
        if self.res == 0 {
            return Vec::new();
        }
        let keys: Vec<MapKey> = lights.iter().map(|l| self.key(l)).collect();
        lights
            .iter()
            .zip(&keys)
            .map(|(l, &key)| self.for_light(mesh, l, key, &keys))
            .collect()
    }

    fn key(&self, light: &LightPlace) -> MapKey {
        let (beam, place) = match *light {
            LightPlace::Point(p) => (false, p),
            LightPlace::Beam(axis) => (true, axis),
        };
        MapKey {
            beam,
            place: place.to_array().map(f32::to_bits),
            res: self.res,
        }
    }

    /// The map of `light` (whose key is `key`), built if this is its second time and there is
    /// room: a map evicts the oldest kept map no light of this set (`set`) uses, so a set of
    /// more lights than [`KEPT_MAPS`] keeps maps for some of them instead of rebuilding them
    /// all in turn.
    fn for_light(
        &self,
        mesh: &TriMesh,
        light: &LightPlace,
        key: MapKey,
        set: &[MapKey],
    ) -> Option<Arc<OccluderMap>> {
        {
            // A poisoned lock only means another thread panicked while holding it: what it
            // holds is whole (a map is built before it is inserted).
            let mut recent = self.recent.lock().unwrap_or_else(|e| e.into_inner());
            if let Some((_, map)) = recent.maps.iter().find(|(k, _)| *k == key) {
                return Some(Arc::clone(map));
            }
            match recent.seen.iter().position(|k| *k == key) {
                Some(at) => {
                    if recent.maps.len() >= KEPT_MAPS
                        && recent.maps.iter().all(|(k, _)| set.contains(k))
                    {
                        return None;
                    }
                    recent.seen.remove(at);
                }
                None => {
                    if recent.seen.len() >= SEEN_PLACES {
                        recent.seen.pop_front();
                    }
                    recent.seen.push_back(key);
                    return None;
                }
            }
        }
        let map = Arc::new(OccluderMap::new(
            mesh,
            &self.tree,
            light,
            self.res,
            self.shadow_end,
        )?);
        let mut recent = self.recent.lock().unwrap_or_else(|e| e.into_inner());
        if recent.maps.len() >= KEPT_MAPS {
            match recent.maps.iter().position(|(k, _)| !set.contains(k)) {
                Some(at) => {
                    recent.maps.remove(at);
                }
                // Another thread's set filled the room meanwhile: use the map, keep none.
                None => return Some(map),
            }
        }
        recent.maps.push_back((key, Arc::clone(&map)));
        Some(map)
    }
}

/// The occluder map of one light: see the module doc.
pub struct OccluderMap {
    projection: Projection,
    faces: Vec<Face>,
    /// `SHADOW_END`'s share of a segment left untraced is within reach of no covering
    /// triangle closer than this to a point light: rays from farther are traced.
    reach: f32,
    /// The absolute depth margin.
    slack: f32,
}

/// How directions map onto cells.
enum Projection {
    /// Six faces round the light: face `2a + (sign < 0)` looks along axis `a` with that sign.
    Cube { light: Vec3, res: u32 },
    /// One grid across the beam: `(x · u − origin[0]) / cell` and `(x · v − origin[1]) / cell`,
    /// depth `−x · w` with `w` pointing towards the light.
    Beam {
        u: Vec3,
        v: Vec3,
        w: Vec3,
        origin: [f32; 2],
        cell: f32,
        size: [u32; 2],
    },
}

/// One face's cells: per cell the covering depth (infinite where none) and the triangle that
/// gives it, and per tile the deepest of its cells.
struct Face {
    width: u32,
    height: u32,
    depth: Vec<f32>,
    blocker: Vec<u32>,
    tiles: Vec<f32>,
}

/// A point of a cell grid: where on the face, and how deep the ray along it lies.
struct Projected {
    face: usize,
    x: f32,
    y: f32,
    depth: f32,
}

/// A triangle's plane, in the terms a face's depth needs.
#[derive(Clone, Copy)]
struct Plane {
    n: Vec3,
    /// `n · (p0 − light)` for a cube, `n · p0` for a beam.
    h: f32,
}

impl OccluderMap {
    /// The map of `light` over `mesh`, `res` cells a side of a cube face (a beam takes as many
    /// cells in all), for shadow rays traced up to `shadow_end` of a point light's distance.
    /// `None` where it could answer nothing: an empty mesh, a zero resolution.
    pub fn new(
        mesh: &TriMesh,
        tree: &OccluderTree,
        light: &LightPlace,
        res: u32,
        shadow_end: f32,
    ) -> Option<OccluderMap> {
        let root = tree.nodes.first()?;
        if res == 0 || mesh.is_empty() {
            return None;
        }
        let (lo, hi) = (Vec3::from(root.min), Vec3::from(root.max));
        let magnitude = lo.abs().max(hi.abs()).max_element();
        let scene = (hi - lo)
            .max_element()
            .max(magnitude)
            .max(f32::MIN_POSITIVE);
        let projection = match *light {
            LightPlace::Point(position) => {
                if !position.is_finite() {
                    return None;
                }
                Projection::Cube {
                    light: position,
                    res,
                }
            }
            LightPlace::Beam(axis) => {
                let w = -axis;
                let (u, v) = w.any_orthonormal_pair();
                let corners = box_corners(lo, hi);
                let (mut u0, mut u1, mut v0, mut v1) = (f32::MAX, f32::MIN, f32::MAX, f32::MIN);
                for c in corners {
                    u0 = u0.min(c.dot(u));
                    u1 = u1.max(c.dot(u));
                    v0 = v0.min(c.dot(v));
                    v1 = v1.max(c.dot(v));
                }
                // Six cube faces' worth of cells, square, over the scene's shadow.
                let cells = 6.0 * (res as f32) * (res as f32);
                let cell = ((u1 - u0) * (v1 - v0) / cells).sqrt().max(scene * 1e-6);
                let size = [
                    (((u1 - u0) / cell).ceil() as u32).clamp(1, 16 * res),
                    (((v1 - v0) / cell).ceil() as u32).clamp(1, 16 * res),
                ];
                Projection::Beam {
                    u,
                    v,
                    w,
                    origin: [u0, v0],
                    cell,
                    size,
                }
            }
        };
        let scale = match projection {
            Projection::Cube { light, .. } => scene.max(light.abs().max_element()),
            Projection::Beam { .. } => scene,
        };
        let mut map = OccluderMap {
            projection,
            faces: Vec::new(),
            reach: NEAR_SHARE * scale * 0.5 / (1.0 - shadow_end),
            slack: SCALE_MARGIN * scale,
        };
        let near = NEAR_SHARE * scale;
        let face_count = match map.projection {
            Projection::Cube { .. } => 6,
            Projection::Beam { .. } => 1,
        };
        let faces: Vec<Face> = (0..face_count)
            .into_par_iter()
            .map(|f| map.build_face(f, mesh.triangles(), tree, near))
            .collect();
        map.faces = faces;
        Some(map)
    }

    /// The triangle (an index into [`TriMesh::triangles`]) that proves the shadow ray from `p`
    /// towards the light blocked, `distance` being the light's distance (infinite for a
    /// directional light), or `None` where the map cannot tell: the ray must be traced.
    #[inline]
    pub fn blocker(&self, p: Vec3, distance: f32) -> Option<u32> {
        if let Projection::Cube { .. } = self.projection
            && !(distance.is_finite() && distance < self.reach)
        {
            return None;
        }
        let at = self.project(p)?;
        let face = &self.faces[at.face];
        if !(at.x >= 0.0 && at.y >= 0.0) {
            return None;
        }
        let (i, j) = (at.x as u32, at.y as u32);
        if i >= face.width || j >= face.height {
            return None;
        }
        let k = (j * face.width + i) as usize;
        let bound = face.depth[k];
        (bound < at.depth - (DEPTH_MARGIN * at.depth.abs() + self.slack)).then(|| face.blocker[k])
    }

    /// How many cells hold a covering triangle, and how many cells there are.
    pub fn coverage(&self) -> (usize, usize) {
        let covered = self
            .faces
            .iter()
            .map(|f| f.depth.iter().filter(|d| d.is_finite()).count())
            .sum();
        let all = self.faces.iter().map(|f| f.depth.len()).sum();
        (covered, all)
    }

    /// Where `x` falls on the cell grid, and its depth.
    #[inline]
    fn project(&self, x: Vec3) -> Option<Projected> {
        match self.projection {
            Projection::Cube { light, res } => {
                let q = x - light;
                let a = q.abs();
                let axis = if a.x >= a.y && a.x >= a.z {
                    0
                } else if a.y >= a.z {
                    1
                } else {
                    2
                };
                let z = a[axis];
                if z.is_nan() || z <= 0.0 {
                    return None;
                }
                let face = 2 * axis + usize::from(q[axis] < 0.0);
                let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
                let half = 0.5 * res as f32;
                Some(Projected {
                    face,
                    x: (q[b] / z + 1.0) * half,
                    y: (q[c] / z + 1.0) * half,
                    depth: q.length(),
                })
            }
            Projection::Beam {
                u,
                v,
                w,
                origin,
                cell,
                ..
            } => Some(Projected {
                face: 0,
                x: (x.dot(u) - origin[0]) / cell,
                y: (x.dot(v) - origin[1]) / cell,
                depth: -x.dot(w),
            }),
        }
    }

    /// Face `f`'s cells, filled front to back through the BVH.
    fn build_face(&self, f: usize, tris: &[MeshTri], tree: &OccluderTree, near: f32) -> Face {
        let nodes = &tree.nodes;
        let (width, height) = match self.projection {
            Projection::Cube { res, .. } => (res, res),
            Projection::Beam { size, .. } => (size[0], size[1]),
        };
        let tiles_x = width.div_ceil(TILE);
        let tiles_y = height.div_ceil(TILE);
        let mut face = Face {
            width,
            height,
            depth: vec![f32::INFINITY; (width * height) as usize],
            blocker: vec![u32::MAX; (width * height) as usize],
            tiles: vec![f32::INFINITY; (tiles_x * tiles_y) as usize],
        };
        let mut stack: Vec<u32> = vec![0];
        while let Some(at) = stack.pop() {
            let node = &nodes[at as usize];
            let (lo, hi) = (Vec3::from(node.min), Vec3::from(node.max));
            // Too fine to cover a whole cell anywhere under this node: a cube's cells are
            // at least 0.94/res radians wide (at a face's corners), a beam's `cell` wide.
            let too_fine = match self.projection {
                Projection::Cube { light, res } => {
                    tree.span[at as usize] * (res as f32)
                        < 0.9 * (light.clamp(lo, hi) - light).length()
                }
                Projection::Beam { cell, .. } => tree.span[at as usize] < cell,
            };
            if too_fine {
                continue;
            }
            let Some((rect, nearest)) = self.footprint(f, lo, hi, width, height) else {
                continue;
            };
            if face.deepest_tile(rect, tiles_x) <= nearest {
                continue;
            }
            if node.prim_count > 0 {
                let first = node.first_index as usize;
                for (k, tri) in tris[first..first + node.prim_count as usize]
                    .iter()
                    .enumerate()
                {
                    self.cover(f, &mut face, tiles_x, tri, (first + k) as u32, near);
                }
            } else {
                let (a, b) = (node.first_index, node.first_index + 1);
                // Nearer child last, so it is taken first.
                let da = self.node_depth(&nodes[a as usize]);
                let db = self.node_depth(&nodes[b as usize]);
                if da <= db {
                    stack.extend([b, a]);
                } else {
                    stack.extend([a, b]);
                }
            }
        }
        face
    }

    /// A lower bound on the depth of anything in a node.
    fn node_depth(&self, node: &MeshNode) -> f32 {
        let (lo, hi) = (Vec3::from(node.min), Vec3::from(node.max));
        match self.projection {
            Projection::Cube { light, .. } => (light.clamp(lo, hi) - light).length(),
            Projection::Beam { w, .. } => box_corners(lo, hi)
                .iter()
                .map(|c| -c.dot(w))
                .fold(f32::INFINITY, f32::min),
        }
    }

    /// The cells (a half-open rectangle `[x0, x1) × [y0, y1)`) a box's directions can reach on
    /// face `f`, and a lower bound on its depth; `None` where it reaches none of them.
    fn footprint(
        &self,
        f: usize,
        lo: Vec3,
        hi: Vec3,
        width: u32,
        height: u32,
    ) -> Option<([u32; 4], f32)> {
        let whole = [0, width, 0, height];
        match self.projection {
            Projection::Cube { light, res } => {
                let (axis, sign, b, c) = face_axes(f);
                let nearest = (light.clamp(lo, hi) - light).length();
                let corners = box_corners(lo - light, hi - light);
                let zs = corners.map(|q| sign * q[axis]);
                if zs.iter().all(|&z| z <= 0.0) {
                    return None;
                }
                if zs.iter().any(|&z| z <= 0.0) {
                    return Some((whole, nearest));
                }
                let half = 0.5 * res as f32;
                let (mut x0, mut x1, mut y0, mut y1) = (f32::MAX, f32::MIN, f32::MAX, f32::MIN);
                for (q, z) in corners.iter().zip(zs) {
                    let (x, y) = ((q[b] / z + 1.0) * half, (q[c] / z + 1.0) * half);
                    x0 = x0.min(x);
                    x1 = x1.max(x);
                    y0 = y0.min(y);
                    y1 = y1.max(y);
                }
                clip_rect([x0, x1, y0, y1], width, height).map(|r| (r, nearest))
            }
            Projection::Beam {
                u,
                v,
                w,
                origin,
                cell,
                ..
            } => {
                let corners = box_corners(lo, hi);
                let (mut x0, mut x1, mut y0, mut y1) = (f32::MAX, f32::MIN, f32::MAX, f32::MIN);
                let mut nearest = f32::INFINITY;
                for q in corners {
                    let (x, y) = ((q.dot(u) - origin[0]) / cell, (q.dot(v) - origin[1]) / cell);
                    x0 = x0.min(x);
                    x1 = x1.max(x);
                    y0 = y0.min(y);
                    y1 = y1.max(y);
                    nearest = nearest.min(-q.dot(w));
                }
                clip_rect([x0, x1, y0, y1], width, height).map(|r| (r, nearest))
            }
        }
    }

    /// Writes triangle `id` into the cells of face `f` it covers whole, where it is nearer
    /// than what they hold.
    fn cover(&self, f: usize, face: &mut Face, tiles_x: u32, tri: &MeshTri, id: u32, near: f32) {
        let p0 = Vec3::from(tri.p0);
        let (e1, e2) = (Vec3::from(tri.e1), Vec3::from(tri.e2));
        let corners = [p0, p0 + e1, p0 + e2];
        let span = e1.length().max(e2.length()).max((e2 - e1).length());
        let too_fine = match self.projection {
            Projection::Cube { light, res } => {
                let nearest = corners
                    .iter()
                    .map(|c| (*c - light).length())
                    .fold(f32::INFINITY, f32::min)
                    - span;
                span * (res as f32) <= 0.9 * nearest
            }
            Projection::Beam { cell, .. } => span < cell,
        };
        if too_fine {
            return;
        }
        let n = e1.cross(e2);
        let n_len = n.length();
        if !(n_len.is_finite() && n_len > 0.0) {
            return;
        }
        // The polygon on the face, in cell units, and the plane's terms.
        let mut poly = [[0.0f32; 2]; 4];
        let count;
        let plane;
        match self.projection {
            Projection::Cube { light, res } => {
                let h = n.dot(p0 - light);
                let distance = h.abs() / n_len;
                if !(distance.is_finite() && distance >= near) {
                    return;
                }
                if span > MAX_SPAN * distance {
                    return;
                }
                let (axis, sign, b, c) = face_axes(f);
                let q = corners.map(|p| p - light);
                let z = q.map(|q| sign * q[axis]);
                // Clipped to the half-space in front of the face, at a depth where nothing
                // lies anyway (`near`): the part kept is a subset of the triangle.
                let mut clipped = [Vec3::ZERO; 4];
                let mut m = 0;
                for k in 0..3 {
                    let (qa, za) = (q[k], z[k]);
                    let (qb, zb) = (q[(k + 1) % 3], z[(k + 1) % 3]);
                    if za >= near {
                        clipped[m] = qa;
                        m += 1;
                    }
                    if (za >= near) != (zb >= near) {
                        let t = (near - za) / (zb - za);
                        clipped[m] = qa + (qb - qa) * t;
                        m += 1;
                    }
                }
                if m < 3 {
                    return;
                }
                let half = 0.5 * res as f32;
                for k in 0..m {
                    let zk = sign * clipped[k][axis];
                    poly[k] = [
                        (clipped[k][b] / zk + 1.0) * half,
                        (clipped[k][c] / zk + 1.0) * half,
                    ];
                }
                count = m;
                plane = Plane { n, h };
            }
            Projection::Beam {
                u, v, origin, cell, ..
            } => {
                for k in 0..3 {
                    poly[k] = [
                        (corners[k].dot(u) - origin[0]) / cell,
                        (corners[k].dot(v) - origin[1]) / cell,
                    ];
                }
                count = 3;
                plane = Plane { n, h: n.dot(p0) };
            }
        }
        let poly = &poly[..count];
        // Nothing of the triangle lies shallower than this: where a cell already holds as
        // shallow a triangle, this one cannot improve it.
        let nearest = match self.projection {
            Projection::Cube { .. } => plane.h.abs() / n_len,
            Projection::Beam { w, .. } => corners
                .iter()
                .map(|c| -c.dot(w))
                .fold(f32::INFINITY, f32::min),
        };
        // Edges as unit-normal half-planes facing in: e(x) = a·x + b·y + c ≥ margin.
        let area: f32 = (0..count)
            .map(|k| {
                let (p, q) = (poly[k], poly[(k + 1) % count]);
                p[0] * q[1] - q[0] * p[1]
            })
            .sum();
        let perimeter: f32 = (0..count)
            .map(|k| {
                let (p, q) = (poly[k], poly[(k + 1) % count]);
                ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2)).sqrt()
            })
            .sum();
        // A convex polygon holding a disc of radius r has area at least r times half its
        // perimeter, and a whole cell holds a disc of radius 1/2: a sliver (or a polygon
        // smaller than a cell, or one not finite) covers none, whatever its extent.
        if !(perimeter.is_finite() && area.abs() >= 0.5 * perimeter) {
            return;
        }
        let turn = area.signum();
        let mut edges = [[0.0f32; 3]; 4];
        for k in 0..count {
            let (p, q) = (poly[k], poly[(k + 1) % count]);
            let (dx, dy) = (q[0] - p[0], q[1] - p[1]);
            let len = (dx * dx + dy * dy).sqrt();
            if !(len.is_finite() && len > 0.0) {
                return;
            }
            // Inward normal of a counter-clockwise edge is (−dy, dx).
            let (a, b) = (-dy * turn / len, dx * turn / len);
            edges[k] = [a, b, -(a * p[0] + b * p[1])];
        }
        let edges = &edges[..count];
        let (mut x0, mut x1, mut y0, mut y1) = (f32::MAX, f32::MIN, f32::MAX, f32::MIN);
        for p in poly {
            x0 = x0.min(p[0]);
            x1 = x1.max(p[0]);
            y0 = y0.min(p[1]);
            y1 = y1.max(p[1]);
        }
        let Some([cx0, cx1, cy0, cy1]) = clip_rect([x0, x1, y0, y1], face.width, face.height)
        else {
            return;
        };
        if face.deepest_tile([cx0, cx1, cy0, cy1], tiles_x) <= nearest {
            return;
        }
        let inside = |x: f32, y: f32| {
            edges
                .iter()
                .all(|e| e[0] * x + e[1] * y + e[2] >= EDGE_MARGIN)
        };
        // The cells written, to refresh their tiles.
        let mut wrote = [u32::MAX, 0, u32::MAX, 0];
        for j in cy0..cy1 {
            // Per edge a·x ≥ G for both corner rows gives the row's run of candidate cells;
            // each candidate is then checked corner by corner, so rounding here can only
            // lose a cell, never add one.
            let (y0, y1) = (j as f32, j as f32 + 1.0);
            let (mut lo, mut hi) = (cx0 as f32, cx1 as f32 - 1.0);
            for e in edges {
                let g = (EDGE_MARGIN - e[1] * y0 - e[2]).max(EDGE_MARGIN - e[1] * y1 - e[2]);
                if e[0] > 0.0 {
                    lo = lo.max((g / e[0]).ceil() - 1.0);
                } else if e[0] < 0.0 {
                    hi = hi.min((g / e[0]).floor());
                } else if g > 0.0 {
                    hi = lo - 1.0;
                }
            }
            if lo.is_nan() || hi.is_nan() || lo > hi {
                continue;
            }
            let (i0, i1) = (lo.max(cx0 as f32) as u32, (hi.min(cx1 as f32 - 1.0)) as u32);
            for i in i0..=i1 {
                let k = (j * face.width + i) as usize;
                if face.depth[k] <= nearest {
                    continue;
                }
                let x = i as f32;
                if !(inside(x, y0) && inside(x + 1.0, y0) && inside(x, y1) && inside(x + 1.0, y1)) {
                    continue;
                }
                let Some(depth) = self.cell_depth(f, plane, x, y0) else {
                    continue;
                };
                if depth < face.depth[k] {
                    face.depth[k] = depth;
                    face.blocker[k] = id;
                    wrote = [
                        wrote[0].min(i),
                        wrote[1].max(i + 1),
                        wrote[2].min(j),
                        wrote[3].max(j + 1),
                    ];
                }
            }
        }
        if wrote[0] < wrote[1] {
            face.refresh_tiles(wrote, tiles_x);
        }
    }

    /// The deepest a plane lies within cell `(x, y)` of face `f` widened by [`EDGE_MARGIN`]:
    /// its depth at the widened cell's corners, the largest. `None` where a corner's line
    /// misses the plane in front.
    fn cell_depth(&self, f: usize, plane: Plane, x: f32, y: f32) -> Option<f32> {
        let m = EDGE_MARGIN;
        let corners = [
            (x - m, y - m),
            (x + 1.0 + m, y - m),
            (x - m, y + 1.0 + m),
            (x + 1.0 + m, y + 1.0 + m),
        ];
        let mut deepest = f32::MIN;
        match self.projection {
            Projection::Cube { res, .. } => {
                let (axis, sign, b, c) = face_axes(f);
                let scale = 2.0 / res as f32;
                for (cx, cy) in corners {
                    let mut dir = Vec3::ZERO;
                    dir[axis] = sign;
                    dir[b] = cx * scale - 1.0;
                    dir[c] = cy * scale - 1.0;
                    let t = plane.h / plane.n.dot(dir);
                    if !(t > 0.0 && t.is_finite()) {
                        return None;
                    }
                    deepest = deepest.max(t * dir.length());
                }
            }
            Projection::Beam {
                u,
                v,
                w,
                origin,
                cell,
                ..
            } => {
                let nw = plane.n.dot(w);
                if nw == 0.0 {
                    return None;
                }
                let (nu, nv) = (plane.n.dot(u), plane.n.dot(v));
                for (cx, cy) in corners {
                    let (a, b) = (origin[0] + cx * cell, origin[1] + cy * cell);
                    let height = (plane.h - a * nu - b * nv) / nw;
                    if !height.is_finite() {
                        return None;
                    }
                    deepest = deepest.max(-height);
                }
            }
        }
        Some(deepest)
    }
}

impl Face {
    /// The deepest covering depth among the tiles a rectangle of cells touches (infinite
    /// where a cell holds none).
    fn deepest_tile(&self, [x0, x1, y0, y1]: [u32; 4], tiles_x: u32) -> f32 {
        let mut deepest = f32::MIN;
        for ty in y0 / TILE..y1.div_ceil(TILE) {
            for tx in x0 / TILE..x1.div_ceil(TILE) {
                deepest = deepest.max(self.tiles[(ty * tiles_x + tx) as usize]);
                if deepest == f32::INFINITY {
                    return deepest;
                }
            }
        }
        deepest
    }

    /// Recomputes the tiles a rectangle of cells touches.
    fn refresh_tiles(&mut self, [x0, x1, y0, y1]: [u32; 4], tiles_x: u32) {
        for ty in y0 / TILE..y1.div_ceil(TILE) {
            for tx in x0 / TILE..x1.div_ceil(TILE) {
                let mut deepest = f32::MIN;
                for j in ty * TILE..((ty + 1) * TILE).min(self.height) {
                    let row = (j * self.width) as usize;
                    for i in tx * TILE..((tx + 1) * TILE).min(self.width) {
                        deepest = deepest.max(self.depth[row + i as usize]);
                    }
                }
                self.tiles[(ty * tiles_x + tx) as usize] = deepest;
            }
        }
    }
}

/// A rectangle in cell units `[x0, x1] × [y0, y1]` as the half-open range of the cells it
/// touches, clipped to the face; `None` where it touches none (or is not finite).
fn clip_rect([x0, x1, y0, y1]: [f32; 4], width: u32, height: u32) -> Option<[u32; 4]> {
    if !(x0.is_finite() && x1.is_finite() && y0.is_finite() && y1.is_finite()) {
        return None;
    }
    let lo = |v: f32, n: u32| v.floor().clamp(0.0, n as f32) as u32;
    let hi = |v: f32, n: u32| (v.floor() + 1.0).clamp(0.0, n as f32) as u32;
    let r = [lo(x0, width), hi(x1, width), lo(y0, height), hi(y1, height)];
    (r[0] < r[1] && r[2] < r[3]).then_some(r)
}

/// Cube face `f`'s axis, the sign it looks along it with, and its two in-plane axes (`x`, `y`).
fn face_axes(f: usize) -> (usize, f32, usize, usize) {
    let axis = f / 2;
    let sign = if f.is_multiple_of(2) { 1.0 } else { -1.0 };
    (axis, sign, (axis + 1) % 3, (axis + 2) % 3)
}

fn box_corners(lo: Vec3, hi: Vec3) -> [Vec3; 8] {
    std::array::from_fn(|k| {
        Vec3::new(
            if k & 1 == 0 { lo.x } else { hi.x },
            if k & 2 == 0 { lo.y } else { hi.y },
            if k & 4 == 0 { lo.z } else { hi.z },
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::direct::{PreparedLight, SHADOW_END, light_sample};
    use crate::light::Light;
    use crate::trimesh::{extent_of, intersect, offset_origin};

    fn place(light: &PreparedLight) -> LightPlace {
        light.place()
    }

    /// A small deterministic generator (xorshift), so the scenes are the same on every run.
    struct Rng(u64);

    impl Rng {
        fn next(&mut self) -> f32 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            (self.0 >> 40) as f32 / (1u64 << 24) as f32
        }

        fn range(&mut self, lo: f32, hi: f32) -> f32 {
            lo + (hi - lo) * self.next()
        }
    }

    /// The twelve triangles of a box's faces.
    fn cuboid(out: &mut Vec<[Vec3; 3]>, lo: Vec3, hi: Vec3) {
        let c = box_corners(lo, hi);
        for [a, b, cc, d] in [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ] {
            out.push([c[a], c[b], c[cc]]);
            out.push([c[a], c[cc], c[d]]);
        }
    }

    /// A walled level: a floor, four rooms' walls with doorways (thin boxes), boxes on the
    /// floor, a ceiling in pieces, and loose triangles of every size, some of them huge and
    /// near the light, some tiny.
    fn level(rng: &mut Rng) -> Vec<[Vec3; 3]> {
        let mut t = Vec::new();
        cuboid(
            &mut t,
            Vec3::new(-10.0, -0.2, -10.0),
            Vec3::new(10.0, 0.0, 10.0),
        );
        for k in 0..4 {
            let x = -6.0 + 4.0 * k as f32;
            let door = rng.range(-6.0, 5.0);
            cuboid(
                &mut t,
                Vec3::new(x, 0.0, -10.0),
                Vec3::new(x + 0.1, 3.0, door),
            );
            cuboid(
                &mut t,
                Vec3::new(x, 0.0, door + 1.0),
                Vec3::new(x + 0.1, 3.0, 10.0),
            );
        }
        for _ in 0..30 {
            let lo = Vec3::new(rng.range(-9.0, 8.0), 0.0, rng.range(-9.0, 8.0));
            let size = Vec3::new(
                rng.range(0.1, 1.5),
                rng.range(0.1, 2.0),
                rng.range(0.1, 1.5),
            );
            cuboid(&mut t, lo, lo + size);
        }
        for i in 0..8 {
            for j in 0..8 {
                let lo = Vec3::new(-10.0 + 2.5 * i as f32, 3.0, -10.0 + 2.5 * j as f32);
                let hi = lo + Vec3::new(2.5, 0.0, 2.5);
                t.push([lo, Vec3::new(hi.x, 3.0, lo.z), hi]);
                t.push([lo, hi, Vec3::new(lo.x, 3.0, hi.z)]);
            }
        }
        for _ in 0..200 {
            let c = Vec3::new(
                rng.range(-9.0, 9.0),
                rng.range(0.0, 3.0),
                rng.range(-9.0, 9.0),
            );
            let s = [0.01, 0.2, 1.0, 4.0][(rng.next() * 4.0) as usize % 4];
            let mut corner = || c + Vec3::new(rng.range(-s, s), rng.range(-s, s), rng.range(-s, s));
            t.push([corner(), corner(), corner()]);
        }
        t
    }

    fn lights(rng: &mut Rng) -> Vec<PreparedLight> {
        let mut out = Vec::new();
        for _ in 0..3 {
            let position = [
                rng.range(-9.0, 9.0),
                rng.range(0.5, 2.8),
                rng.range(-9.0, 9.0),
            ];
            out.push(Light::Point {
                position,
                color: [1.0; 3],
                intensity: 10.0,
                range: None,
                name: None,
            });
            out.push(Light::Spot {
                position,
                direction: [rng.range(-1.0, 1.0), -1.0, rng.range(-1.0, 1.0)],
                color: [1.0; 3],
                intensity: 10.0,
                range: None,
                inner_cone_angle: 0.3,
                outer_cone_angle: 0.9,
                name: None,
            });
        }
        for direction in [[-0.4, -1.0, -0.3], [0.2, -0.3, 0.9], [0.0, -1.0, 0.0]] {
            out.push(Light::Directional {
                direction,
                color: [1.0; 3],
                intensity: 3.0,
                name: None,
            });
        }
        // A light inside a box on the floor (walled in on every side) and one right by a wall.
        out.push(Light::Point {
            position: [-5.95, 1.0, 7.0],
            color: [1.0; 3],
            intensity: 10.0,
            range: None,
            name: None,
        });
        out.into_iter()
            .filter_map(|l| PreparedLight::new(&l))
            .collect()
    }

    /// Every ray a map calls blocked is blocked, by the triangle it names, on surface points
    /// and points in the open, for point, spot and directional lights at several
    /// resolutions; and the maps do answer most of the blocked rays of such a level, so the
    /// check is not vacuous.
    #[test]
    fn a_map_never_calls_an_open_ray_blocked_and_proves_most_blocked_ones() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        let tris = level(&mut rng);
        let extent = extent_of(tris.iter().flatten());
        let mesh = TriMesh::new(tris.iter().map(|&t| (t, false)));
        let tree = OccluderTree::new(&mesh);
        let lights = lights(&mut rng);
        // Points on the surfaces, pushed off towards both sides, and points in the open.
        let mut points = Vec::new();
        for _ in 0..6000 {
            let t = tris[(rng.next() * tris.len() as f32) as usize % tris.len()];
            let (mut a, mut b) = (rng.next(), rng.next());
            if a + b > 1.0 {
                (a, b) = (1.0 - a, 1.0 - b);
            }
            let p = t[0] + (t[1] - t[0]) * a + (t[2] - t[0]) * b;
            let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
            if n == Vec3::ZERO {
                continue;
            }
            points.push((offset_origin(p, n, extent), n));
            points.push((offset_origin(p, -n, extent), -n));
        }
        for _ in 0..3000 {
            let p = Vec3::new(
                rng.range(-10.0, 10.0),
                rng.range(0.0, 3.0),
                rng.range(-10.0, 10.0),
            );
            let n = Vec3::new(
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
            );
            points.push((p, n.normalize_or(Vec3::Y)));
        }
        for res in [16, 64, 128, 256] {
            let (mut blocked, mut proved) = (0usize, 0usize);
            for light in &lights {
                let map = OccluderMap::new(&mesh, &tree, &place(light), res, SHADOW_END)
                    .expect("a map of a level");
                for &(p, n) in &points {
                    let Some(l) = light_sample(light, p, n) else {
                        continue;
                    };
                    let t_max = l.distance * SHADOW_END;
                    let traced = mesh.occluded(p, l.dir, t_max);
                    blocked += usize::from(traced);
                    if let Some(b) = map.blocker(p, l.distance) {
                        proved += 1;
                        assert!(
                            traced,
                            "{light:?} at {res}: the map blocks an open ray from {p}"
                        );
                        let tri = &mesh.triangles()[b as usize];
                        assert!(
                            intersect(tri, p, l.dir, t_max).is_some(),
                            "{light:?} at {res}: triangle {b} does not block the ray from {p}"
                        );
                    }
                }
            }
            let share = proved as f64 / blocked.max(1) as f64;
            eprintln!("{res} cells a side: {proved} of {blocked} blocked rays proved ({share:.2})");
            assert!(blocked > 10_000, "the level blocks rays: {blocked}");
            if res >= 64 {
                assert!(
                    share > 0.4,
                    "at {res} the maps prove {share:.2} of the blocked rays"
                );
            }
        }
    }

    /// Nothing to map: no map, and a map answers nothing outside its grid.
    #[test]
    fn empty_scenes_and_far_points_are_traced() {
        let light = PreparedLight::new(&Light::Point {
            position: [0.0, 1.0, 0.0],
            color: [1.0; 3],
            intensity: 1.0,
            range: None,
            name: None,
        })
        .unwrap();
        let empty = TriMesh::new([]);
        assert!(
            OccluderMap::new(
                &empty,
                &OccluderTree::new(&empty),
                &place(&light),
                64,
                SHADOW_END
            )
            .is_none()
        );
        let mut t = Vec::new();
        cuboid(&mut t, Vec3::splat(-1.0), Vec3::new(1.0, 0.5, 1.0));
        let mesh = TriMesh::new(t.iter().map(|&t| (t, false)));
        let tree = OccluderTree::new(&mesh);
        assert!(OccluderMap::new(&mesh, &tree, &place(&light), 0, SHADOW_END).is_none());
        let map = OccluderMap::new(&mesh, &tree, &place(&light), 64, SHADOW_END).unwrap();
        let (covered, all) = map.coverage();
        assert!(covered > 0 && covered < all, "{covered} of {all}");
        // Under the box, seen through its top (off the diagonals its faces are cut along):
        // blocked, and proved.
        let under = Vec3::new(0.6, -2.0, -0.3);
        assert!(
            map.blocker(under, (light.position - under).length())
                .is_some()
        );
        // Far beyond the scene's size from the light: traced, whatever the cells hold.
        let far = Vec3::new(0.0, -1e4, 0.0);
        assert!(map.blocker(far, (light.position - far).length()).is_none());
        let sun = PreparedLight::new(&Light::Directional {
            direction: [0.0, -1.0, 0.0],
            color: [1.0; 3],
            intensity: 1.0,
            name: None,
        })
        .unwrap();
        let beam = OccluderMap::new(&mesh, &tree, &place(&sun), 64, SHADOW_END).unwrap();
        assert!(beam.blocker(under, f32::INFINITY).is_some());
        // Beside the box's shadow, outside the grid: traced.
        assert!(
            beam.blocker(Vec3::new(5.0, -2.0, 0.0), f32::INFINITY)
                .is_none()
        );
        // Above the box: in the open.
        assert!(
            beam.blocker(Vec3::new(0.0, 2.0, 0.0), f32::INFINITY)
                .is_none()
        );
    }

    /// A light gets its map the second time its place is asked for, whatever its colour or
    /// intensity, and keeps it; a light that moves every time gets none; resolution 0 builds
    /// nothing.
    #[test]
    fn a_light_that_stays_put_gets_its_map_the_second_time() {
        let mut t = Vec::new();
        cuboid(&mut t, Vec3::splat(-1.0), Vec3::new(1.0, 0.5, 1.0));
        let mesh = TriMesh::new(t.iter().map(|&t| (t, false)));
        let point = |x: f32, intensity: f32| {
            PreparedLight::new(&Light::Point {
                position: [x, 1.0, 0.0],
                color: [1.0; 3],
                intensity,
                range: None,
                name: None,
            })
            .unwrap()
        };
        let places = |lights: &[PreparedLight]| lights.iter().map(place).collect::<Vec<_>>();
        let mut maps = OccluderMaps::new(&mesh, SHADOW_END);
        assert!(maps.for_lights(&mesh, &places(&[point(0.0, 1.0)]))[0].is_none());
        let second = maps.for_lights(&mesh, &places(&[point(0.0, 5.0)]));
        let third = maps.for_lights(&mesh, &places(&[point(0.0, 2.0)]));
        let (Some(a), Some(b)) = (&second[0], &third[0]) else {
            panic!("a light asked for twice has a map");
        };
        assert!(Arc::ptr_eq(a, b), "the map is kept, not rebuilt");
        for k in 0..40 {
            assert!(
                maps.for_lights(&mesh, &places(&[point(0.01 * k as f32, 1.0)]))[0].is_none()
                    || k == 0
            );
        }
        assert!(maps.kept() <= KEPT_MAPS);
        // A set of more lights than there is room for keeps maps for some of them, the same
        // ones from one time to the next, rather than rebuilding them in turn.
        let many: Vec<PreparedLight> = (0..KEPT_MAPS + 4)
            .map(|k| point(-0.9 + 0.05 * k as f32, 1.0))
            .collect();
        maps.for_lights(&mesh, &places(&many));
        let second = maps.for_lights(&mesh, &places(&many));
        let third = maps.for_lights(&mesh, &places(&many));
        assert_eq!(second.iter().flatten().count(), KEPT_MAPS);
        for (a, b) in second.iter().zip(&third) {
            match (a, b) {
                (Some(a), Some(b)) => assert!(Arc::ptr_eq(a, b)),
                (None, None) => {}
                _ => panic!("a light's map came or went between two asks of the same set"),
            }
        }
        assert_eq!(maps.kept(), KEPT_MAPS);
        maps.set_resolution(0);
        assert!(
            maps.for_lights(&mesh, &places(&[point(0.0, 1.0)]))
                .is_empty()
        );
        assert_eq!(maps.kept(), 0);
    }
}
