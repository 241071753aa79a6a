//! Which open space a piece of surface faces: the empty space of a scene cut into the regions its
//! surfaces enclose (docs/design.md §2, step 2).
//!
//! A patch is `(voxel, direction)`, and a voxel of a level can hold surfaces that face different
//! rooms: the two floors either side of a wall, a wall running up past a ceiling into the storey
//! above, or the back of a double-sided wall that faces into the rock of the level beside the
//! front of another that faces the lit corridor. One element standing for all of them averages
//! the lit room's direct light onto the dark one and pours it there: light leaks through walls
//! with no ray ever crossing one. Splitting elements by the space each piece faces removes that
//! path at its root.
//!
//! The spaces are found on a lattice of points finer than the voxels: two neighbouring lattice
//! points see each other when the segment between them crosses no triangle (traced against the
//! original triangles, the same [`TriMesh`] the form-factor rays use). A piece of surface faces
//! the nearest lattice point it can see from just in front of itself ([`Spaces::facing`]). The
//! spaces are taken locally ([`Spaces::local`]): two pieces of a voxel face one space when their
//! points connect within a box around the voxel. Taken over the whole scene, a level is usually
//! one space (open to the sky, its storeys joined by stairs), yet within a voxel the ceiling still
//! parts the wall below it from the wall above. The lattice only ever separates what a surface
//! separates: a doorway narrower than its spacing closes, and then two pieces that face one room
//! get two elements, which costs a row but never an error.

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use crate::trimesh::{TriMesh, offset_origin};

/// The most lattice points a scene gets (a byte each, and three segments traced); a finer lattice
/// would only be asked for by a grid that is mostly empty, whose spaces a coarser one finds too.
pub const MAX_LATTICE_POINTS: u64 = 1 << 22;

/// The open space of a scene on a lattice whose points are the centres of the cells of a grid
/// `origin + i · spacing`: which neighbouring points see each other.
#[derive(Debug, Clone)]
pub struct Spaces {
    origin: DVec3,
    spacing: f64,
    dims: [u32; 3],
    /// Per lattice point (x fastest), bit `a` set when the segment to its neighbour one step up
    /// axis `a` crosses no triangle.
    open: Vec<u8>,
    /// The scene's size, for pushing points off surfaces ([`offset_origin`]).
    extent: f32,
}

/// The spaces within one box of lattice points: which of its points are connected without
/// leaving the box.
#[derive(Debug, Clone)]
pub struct Local {
    lo: [u32; 3],
    size: [u32; 3],
    /// Per point of the box (x fastest), its space, numbered in the order of its first point.
    label: Vec<u32>,
}

impl Local {
    /// The space of lattice point `point` (an index into the whole lattice), if it is in the box.
    pub fn label(&self, spaces: &Spaces, point: usize) -> Option<u32> {
        let c = spaces.coords(point);
        let mut i = 0usize;
        for a in (0..3).rev() {
            let l = c[a].checked_sub(self.lo[a]).filter(|&l| l < self.size[a])?;
            i = i * self.size[a] as usize + l as usize;
        }
        self.label.get(i).copied()
    }

    /// How many spaces the box holds.
    pub fn count(&self) -> usize {
        self.label.iter().max().map_or(0, |&m| m as usize + 1)
    }
}

impl Spaces {
    /// The open space of `mesh` on the lattice of cell centres of the grid
    /// `origin + i · spacing`, `dims` cells per axis. `None` when the lattice would have more
    /// than [`MAX_LATTICE_POINTS`] points or no points at all.
    pub fn new(
        mesh: &TriMesh,
        origin: Vec3,
        spacing: f32,
        dims: [u32; 3],
        extent: f32,
    ) -> Option<Spaces> {
        let points = dims.iter().map(|&d| u64::from(d)).product::<u64>();
        if points == 0 || points > MAX_LATTICE_POINTS || !(spacing > 0.0 && spacing.is_finite()) {
            return None;
        }
        let mut spaces = Spaces {
            origin: origin.as_dvec3(),
            spacing: f64::from(spacing),
            dims,
            open: Vec::new(),
            extent,
        };
        spaces.open = (0..points as usize)
            .into_par_iter()
            .map(|i| {
                let c = spaces.coords(i);
                let from = spaces.centre(c).as_vec3();
                let mut bits = 0u8;
                for axis in 0..3 {
                    if c[axis] + 1 < dims[axis] {
                        let mut dir = Vec3::ZERO;
                        dir[axis] = 1.0;
                        if !mesh.occluded(from, dir, spacing) {
                            bits |= 1 << axis;
                        }
                    }
                }
                bits
            })
            .collect();
        Some(spaces)
    }

    fn coords(&self, i: usize) -> [u32; 3] {
        let (dx, dy) = (self.dims[0] as usize, self.dims[1] as usize);
        [
            (i % dx) as u32,
            ((i / dx) % dy) as u32,
            (i / (dx * dy)) as u32,
        ]
    }

    fn index(&self, c: [u32; 3]) -> usize {
        c[0] as usize
            + self.dims[0] as usize * (c[1] as usize + self.dims[1] as usize * c[2] as usize)
    }

    fn centre(&self, c: [u32; 3]) -> DVec3 {
        self.origin + (DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64) + 0.5) * self.spacing
    }

    /// The spaces within the box of lattice points `lo..hi` (clamped to the lattice): points
    /// are joined only through open segments inside the box, so a wall that only a detour
    /// outside the box gets round still separates.
    pub fn local(&self, lo: [u32; 3], hi: [u32; 3]) -> Local {
        let hi = [0, 1, 2].map(|a| hi[a].min(self.dims[a]));
        let lo = [0, 1, 2].map(|a| lo[a].min(hi[a]));
        let size = [0, 1, 2].map(|a| hi[a] - lo[a]);
        let n = size.iter().map(|&s| s as usize).product::<usize>();
        let mut parent: Vec<u32> = (0..n as u32).collect();
        let stride = [
            1usize,
            size[0] as usize,
            size[0] as usize * size[1] as usize,
        ];
        for z in 0..size[2] {
            for y in 0..size[1] {
                for x in 0..size[0] {
                    let l = [x, y, z];
                    let i = x as usize + stride[1] * y as usize + stride[2] * z as usize;
                    let bits = self.open[self.index([lo[0] + x, lo[1] + y, lo[2] + z])];
                    for a in 0..3 {
                        if bits & (1 << a) != 0 && l[a] + 1 < size[a] {
                            union(&mut parent, i as u32, (i + stride[a]) as u32);
                        }
                    }
                }
            }
        }
        let mut number = vec![u32::MAX; n];
        let mut next = 0u32;
        let label = (0..n)
            .map(|i| {
                let root = find(&mut parent, i as u32) as usize;
                if number[root] == u32::MAX {
                    number[root] = next;
                    next += 1;
                }
                number[root]
            })
            .collect();
        Local { lo, size, label }
    }

    /// The lattice point that the surface at `p` with unit normal `n` (the side that faces it)
    /// looks into: the nearest point in the 4×4×4 block around it that can be seen from just in
    /// front of `p`. `None` when none can (the surface faces a gap narrower than the lattice, or
    /// is boxed in).
    pub fn facing(&self, mesh: &TriMesh, p: Vec3, n: Vec3) -> Option<usize> {
        let q = offset_origin(p, n, self.extent);
        let local = (q.as_dvec3() - self.origin) / self.spacing - 0.5;
        let base = local.floor();
        let mut candidates: Vec<(f64, usize, Vec3)> = Vec::with_capacity(64);
        for dz in -1..=2i64 {
            for dy in -1..=2i64 {
                for dx in -1..=2i64 {
                    let c = [base.x as i64 + dx, base.y as i64 + dy, base.z as i64 + dz];
                    if c.iter()
                        .zip(&self.dims)
                        .any(|(&v, &d)| v < 0 || v >= i64::from(d))
                    {
                        continue;
                    }
                    let c = c.map(|v| v as u32);
                    let to = self.centre(c).as_vec3() - q;
                    // Points behind the surface are never in front of it.
                    if to.dot(n) <= 0.0 {
                        continue;
                    }
                    candidates.push((f64::from(to.length_squared()), self.index(c), to));
                }
            }
        }
        candidates.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        candidates.into_iter().find_map(|(d2, index, to)| {
            let len = d2.sqrt() as f32;
            (len == 0.0 || !mesh.occluded(q, to / len, len)).then_some(index)
        })
    }
}

/// The root of `i`'s set, halving the path on the way.
pub(crate) fn find(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        let up = parent[parent[i as usize] as usize];
        parent[i as usize] = up;
        i = up;
    }
    i
}

/// Join the sets of `a` and `b`; the smaller root wins, so every root is its set's first point.
pub(crate) fn union(parent: &mut [u32], a: u32, b: u32) {
    let (a, b) = (find(parent, a), find(parent, b));
    if a != b {
        let (lo, hi) = (a.min(b), a.max(b));
        parent[hi as usize] = lo;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed box of two rooms (the box spans 0..2 × 0..1 × 0..1) with a wall at x = 1 from
    /// the floor up to `wall_top`: 1 parts the rooms, less leaves an opening above the wall.
    fn rooms(wall_top: f32) -> TriMesh {
        let mut tris = Vec::new();
        let mut quad = |a: Vec3, b: Vec3, c: Vec3, d: Vec3| {
            tris.push(([a, b, c], true));
            tris.push(([a, c, d], true));
        };
        let v = Vec3::new;
        for (x, top) in [(0.0, 1.0), (1.0, wall_top), (2.0, 1.0)] {
            quad(
                v(x, 0.0, 0.0),
                v(x, top, 0.0),
                v(x, top, 1.0),
                v(x, 0.0, 1.0),
            );
        }
        for y in [0.0, 1.0] {
            quad(
                v(0.0, y, 0.0),
                v(2.0, y, 0.0),
                v(2.0, y, 1.0),
                v(0.0, y, 1.0),
            );
        }
        for z in [0.0, 1.0] {
            quad(
                v(0.0, 0.0, z),
                v(2.0, 0.0, z),
                v(2.0, 1.0, z),
                v(0.0, 1.0, z),
            );
        }
        TriMesh::new(tris)
    }

    fn two_rooms() -> TriMesh {
        rooms(1.0)
    }

    fn lattice(mesh: &TriMesh) -> Spaces {
        // Cells of 0.25 from -0.5: points at -0.375, -0.125, ... (never on a wall).
        Spaces::new(mesh, Vec3::splat(-0.5), 0.25, [12, 8, 8], 2.0).unwrap()
    }

    /// The space the surface at `p` facing `n` looks into, among the whole lattice's.
    fn space(s: &Spaces, mesh: &TriMesh, all: &Local, p: Vec3, n: Vec3) -> Option<u32> {
        all.label(s, s.facing(mesh, p, n)?)
    }

    #[test]
    fn a_wall_separates_two_rooms_from_each_other_and_the_outside() {
        let mesh = two_rooms();
        let s = lattice(&mesh);
        let all = s.local([0; 3], [u32::MAX; 3]);
        assert_eq!(all.count(), 3, "outside, left room, right room");
        let up = Vec3::Y;
        let at = |p: Vec3, n: Vec3| space(&s, &mesh, &all, p, n);
        let left = at(Vec3::new(0.5, 0.0, 0.5), up).unwrap();
        let right = at(Vec3::new(1.5, 0.0, 0.5), up).unwrap();
        let outside = at(Vec3::new(0.5, 0.0, 0.5), -up).unwrap();
        assert_ne!(left, right);
        assert_ne!(left, outside);
        assert_ne!(right, outside);
        // Right beside the wall, each side of the floor still sees its own room, and each side
        // of the wall its own.
        assert_eq!(at(Vec3::new(0.99, 0.0, 0.5), up), Some(left));
        assert_eq!(at(Vec3::new(1.01, 0.0, 0.5), up), Some(right));
        assert_eq!(at(Vec3::new(1.0, 0.5, 0.5), -Vec3::X), Some(left));
        assert_eq!(at(Vec3::new(1.0, 0.5, 0.5), Vec3::X), Some(right));
    }

    #[test]
    fn an_opening_joins_the_rooms_but_not_within_a_box_that_leaves_it_out() {
        // The same rooms, but the wall at x = 1 only reaches y = 0.5.
        let mesh = rooms(0.5);
        let s = lattice(&mesh);
        let all = s.local([0; 3], [u32::MAX; 3]);
        assert_eq!(all.count(), 2, "outside and one room");
        let (a, b) = (Vec3::new(0.9, 0.0, 0.5), Vec3::new(1.1, 0.0, 0.5));
        assert_eq!(
            space(&s, &mesh, &all, a, Vec3::Y),
            space(&s, &mesh, &all, b, Vec3::Y)
        );
        // Points y < 0.5 only (lattice rows 2 and 3 are y = 0.125, 0.375): the opening above
        // the wall is outside the box, so the floor's two sides face two spaces there.
        let low = s.local([0, 2, 0], [12, 4, 8]);
        assert_ne!(
            space(&s, &mesh, &low, a, Vec3::Y),
            space(&s, &mesh, &low, b, Vec3::Y)
        );
    }

    #[test]
    fn a_lattice_too_large_is_refused() {
        let mesh = two_rooms();
        assert!(Spaces::new(&mesh, Vec3::ZERO, 1.0, [1 << 11, 1 << 11, 2], 1.0).is_none());
        assert!(Spaces::new(&mesh, Vec3::ZERO, 0.0, [2, 2, 2], 1.0).is_none());
    }
}
