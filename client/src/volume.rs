//! The six-direction irradiance volume of docs/design.md §2 "Clients": how a client turns a frame
//! of per-patch irradiance into something it can sample at any point of its own meshes.
//!
//! # Convention (the viewer's shader does exactly this)
//!
//! - One grid per face direction, indexed by the face code of the proto's `Face` enum:
//!   0 = +X, 1 = −X, 2 = +Y, 3 = −Y, 4 = +Z, 5 = −Z.
//! - Each grid has the layout's `dims` (x × y × z texels, one per voxel), stored x fastest, then
//!   y, then z: texel `(x, y, z)` is at `x + dims.x · (y + dims.y · z)`. That is the order an
//!   `Rgba16Float` 3D texture upload expects (`bytes_per_row = 8 · dims.x`,
//!   `rows_per_image = dims.y`).
//! - The patch on face `f` of voxel `v` is texel `v` of grid `f`: rgb is its indirect irradiance
//!   (W/m² per channel, as the frame carries it), a is coverage, 1 there. Texels with no patch
//!   are `(0, 0, 0, 0)`. Coverage is fixed by the layout; frames only change rgb.
//! - Texel centres sit at voxel centres: world position `p` is texel coordinate
//!   `(p − origin) / voxel_size − 0.5`, i.e. normalised texture coordinate
//!   `(p − origin) / (voxel_size · dims)` with the hardware's linear filter. Outside the grid the
//!   edge texels repeat (clamp-to-edge addressing).
//! - A surface patch is the surface inside one voxel whose side faces one direction most, so a
//!   point `p` of a surface with normal `n` (the seen side's geometric normal) belongs to the
//!   patch of face `dominant_face(n)` (the axis of `n`'s largest component, ties to X, then Y;
//!   its sign, `+` for `n[a] ≥ 0`: the bake's own rule) in the voxel containing `p`,
//!   `floor((p − origin) / voxel_size)`: its *own cell*. Only that face's grid is read; the
//!   other directions' grids hold other surfaces (a wall meeting the floor, the side of a box),
//!   not light arriving at this one.
//! - Between patches the value is interpolated: that grid filtered trilinearly at `p` (texel
//!   centres at voxel centres: the 2 × 2 × 2 texels around `p`, own cell among them, edge texels
//!   repeating outside the grid), with two exceptions. Texels without a patch drop out: the sum
//!   is divided by the filtered coverage (where it is at least [`MIN_COVERAGE`]; below, zero).
//!   And texels across a *separator* from the own cell drop out: a texel that differs from the
//!   own cell along axis `a` is left out when the own cell and its neighbour along `a` (on the
//!   texel's side) hold, between the two of them, patches facing both ways along `a`, which is
//!   what a wall thinner than two voxels between them looks like. So light is interpolated along
//!   a surface but never read from the far side of a thin wall, the other room's floor.
//! - The separators are a seventh grid of the same dims, one byte a voxel: bit `f` (face code)
//!   set when the voxel is separated from its neighbour in direction `f` ([`Volume::separators`];
//!   an `R8Uint` 3D texture). They follow from the layout alone.
//! - Sample at the surface point itself. The patch texel sits at the centre of the voxel the
//!   surface lies in, so no offset is needed (an older convention's "slightly off the surface"
//!   belongs to storing a patch in the empty voxel in front of it); an offset along the normal of
//!   more than half a voxel leaves the patch's voxel.
//!
//! [`Volume::sample`] is the CPU twin of that shader code, for tests and tools. The shader reads
//! the texels and weighs them itself (no hardware filter), so the two agree to f32 rounding of
//! the f16 texels' values, except for points within rounding of a voxel boundary.

use bounce_types::face::dominant_face;
use bounce_wire::frame::{FLAG_CLAMPED, FLAG_NON_FINITE, Frame, FrameHeader, decode_rgb9e5};
use glam::{IVec3, UVec3, Vec3, Vec4};
use half::f16;
use thiserror::Error;

use crate::layout::{Face, Layout};

/// Largest texel count along one axis: wgpu's default `max_texture_dimension_3d`.
pub const MAX_VOLUME_DIM: u32 = 2048;

/// Largest texel count of one direction's grid (each texel is 8 bytes, and there are six grids:
/// 768 MiB at this limit).
pub const MAX_TEXELS: u64 = 1 << 24;

/// Filtered coverage below this is treated as none: dividing by less would amplify the
/// filter's own rounding (a GPU's filter weights have 8 fractional bits).
pub const MIN_COVERAGE: f32 = 1.0 / 256.0;

/// One texel: rgb irradiance and coverage, as an `Rgba16Float` texture stores it.
pub type Texel = [f16; 4];

/// The six grids for one layout, and the most recent frame written into them.
#[derive(Debug, Clone)]
pub struct Volume {
    origin: Vec3,
    voxel_size: f32,
    dims: UVec3,
    /// Indexed by face code.
    grids: [Vec<Texel>; 6],
    /// Per voxel, bit `f` set when a thin wall separates it from its neighbour in direction `f`
    /// (see the module doc).
    separators: Vec<u8>,
    /// Per patch, where its value goes: computed once, so applying a frame is one pass.
    targets: Vec<Target>,
    frame: Option<FrameHeader>,
    /// What the last write had to change, as frame flags (see [`Volume::flags`]).
    flags: u32,
}

#[derive(Debug, Clone, Copy)]
struct Target {
    grid: u8,
    texel: u32,
}

#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum VolumeError {
    #[error(
        "a {dims:?} voxel grid is too large for a volume texture (at most {MAX_VOLUME_DIM} a side \
         and {MAX_TEXELS} texels)"
    )]
    TooLarge { dims: [u32; 3] },
    #[error("the frame has {frame} patches and the layout {layout}: not this scene's frame")]
    PatchCount { frame: usize, layout: usize },
}

impl Volume {
    /// Empty grids (no irradiance yet) with the layout's coverage.
    pub fn new(layout: &Layout) -> Result<Volume, VolumeError> {
        let dims = layout.dims();
        let texels = u64::from(dims.x) * u64::from(dims.y) * u64::from(dims.z);
        if dims.max_element() > MAX_VOLUME_DIM || texels > MAX_TEXELS {
            return Err(VolumeError::TooLarge {
                dims: dims.to_array(),
            });
        }
        // Fits: at most MAX_TEXELS.
        let texels = texels as usize;
        let mut grids: [Vec<Texel>; 6] = std::array::from_fn(|_| vec![[f16::ZERO; 4]; texels]);
        let targets = layout
            .patches()
            .iter()
            .map(|p| {
                let v = p.voxel;
                let texel = v.x + dims.x * (v.y + dims.y * v.z);
                let grid = p.face.code();
                grids[usize::from(grid)][texel as usize][3] = f16::ONE;
                Target { grid, texel }
            })
            .collect();
        let separators = separators(dims, &grids);
        Ok(Volume {
            origin: layout.origin(),
            voxel_size: layout.voxel_size(),
            dims,
            grids,
            separators,
            targets,
            frame: None,
            flags: 0,
        })
    }

    /// Writes a frame's irradiance into the grids.
    pub fn apply(&mut self, frame: &Frame) -> Result<(), VolumeError> {
        self.check_count(frame.header.patch_count as usize)?;
        // RGB9E5 values always fit f16, so the header's flags say all there is.
        self.write(frame.words().map(decode_rgb9e5));
        self.frame = Some(frame.header);
        self.flags = frame.header.flags;
        Ok(())
    }

    /// Writes irradiance computed in-process (one RGB triple a patch, in layout order), for
    /// clients that relight without a server.
    pub fn apply_irradiance(&mut self, irradiance: &[[f32; 3]]) -> Result<(), VolumeError> {
        self.check_count(irradiance.len())?;
        self.flags = self.write(irradiance.iter().copied());
        self.frame = None;
        Ok(())
    }

    fn check_count(&self, count: usize) -> Result<(), VolumeError> {
        if count == self.targets.len() {
            Ok(())
        } else {
            Err(VolumeError::PatchCount {
                frame: count,
                layout: self.targets.len(),
            })
        }
    }

    /// Writes the values as f16, saturating what f16 cannot hold: returns [`FLAG_CLAMPED`] when
    /// a value was above f16's largest (65504, written as that) and [`FLAG_NON_FINITE`] when one
    /// was NaN (written as 0) or infinite, as the frame encoder does. Values from a frame never
    /// need it (RGB9E5's largest, 65408, is below f16's); in-process irradiance can.
    fn write(&mut self, values: impl Iterator<Item = [f32; 3]>) -> u32 {
        let mut flags = 0;
        let mut half = |x: f32| {
            if x.is_nan() {
                flags |= FLAG_NON_FINITE;
                f16::ZERO
            } else if x == f32::INFINITY {
                flags |= FLAG_NON_FINITE;
                f16::MAX
            } else if x > f16::MAX.to_f32() {
                flags |= FLAG_CLAMPED;
                f16::MAX
            } else {
                // Irradiance is never negative; a lossy codec's tiny negatives are not worth a
                // flag (the frame encoder treats them the same).
                f16::from_f32(x.max(0.0))
            }
        };
        for (rgb, t) in values.zip(&self.targets) {
            let [r, g, b] = rgb.map(&mut half);
            self.grids[usize::from(t.grid)][t.texel as usize] = [r, g, b, f16::ONE];
        }
        flags
    }

    /// What the last write had to change, as frame flags: for a frame, its header's
    /// ([`FLAG_CLAMPED`]: the server clamped a value to RGB9E5's largest); for in-process
    /// irradiance, the f16 conversion's. 0 when every value was written as it was.
    pub fn flags(&self) -> u32 {
        self.flags
    }

    /// The header of the last frame applied (`None` before the first, or after in-process
    /// irradiance).
    pub fn frame(&self) -> Option<FrameHeader> {
        self.frame
    }

    /// Texels along X, Y, Z: the 3D texture's extent.
    pub fn dims(&self) -> UVec3 {
        self.dims
    }

    pub fn origin(&self) -> Vec3 {
        self.origin
    }

    pub fn voxel_size(&self) -> f32 {
        self.voxel_size
    }

    /// One direction's grid, x fastest, then y, then z.
    pub fn texels(&self, face: Face) -> &[Texel] {
        &self.grids[usize::from(face.code())]
    }

    /// The same as bytes, for a texture upload.
    pub fn texel_bytes(&self, face: Face) -> &[u8] {
        bytemuck::cast_slice(self.texels(face))
    }

    /// The separator grid (see the module doc), x fastest, then y, then z: the bytes of an
    /// `R8Uint` texture upload (`bytes_per_row = dims.x`, `rows_per_image = dims.y`).
    pub fn separators(&self) -> &[u8] {
        &self.separators
    }

    /// The separator bits of a voxel, `None` outside the grid.
    pub fn separator(&self, voxel: UVec3) -> Option<u8> {
        if voxel.cmpge(self.dims).any() {
            return None;
        }
        Some(self.separators[(voxel.x + self.dims.x * (voxel.y + self.dims.y * voxel.z)) as usize])
    }

    /// The texel of a voxel in every grid, `None` outside the grid.
    pub fn texel(&self, face: Face, voxel: UVec3) -> Option<Texel> {
        if voxel.cmpge(self.dims).any() {
            return None;
        }
        let i = voxel.x + self.dims.x * (voxel.y + self.dims.y * voxel.z);
        Some(self.texels(face)[i as usize])
    }

    /// Indirect irradiance at `position` on a surface whose seen side has `normal`, as the
    /// module doc says: the patch of the normal's dominant face around the position's own
    /// voxel, interpolated. Zero for a zero or non-finite normal.
    pub fn sample(&self, position: Vec3, normal: Vec3) -> [f32; 3] {
        if !(normal.is_finite() && normal.length_squared() > 0.0) {
            return [0.0; 3];
        }
        self.sample_face(dominant_face(normal), position)
            .map_or([0.0; 3], |v| v.to_array())
    }

    /// One grid filtered at `position` as the module doc says (separators respected) and
    /// divided by its coverage; `None` where the coverage is below [`MIN_COVERAGE`].
    pub fn sample_face(&self, face: Face, position: Vec3) -> Option<Vec3> {
        let v = self.filter(face, position);
        (v.w >= MIN_COVERAGE).then(|| v.truncate() / v.w)
    }

    /// Trilinear filter with clamp-to-edge addressing, texel centres at voxel centres, leaving
    /// out the texels across a separator from the own cell.
    fn filter(&self, face: Face, position: Vec3) -> Vec4 {
        if !position.is_finite() {
            return Vec4::ZERO;
        }
        let u = (position - self.origin) / self.voxel_size - 0.5;
        let max = self.dims.as_ivec3() - 1;
        // Clamped in float first so far-away points cannot overflow the integer conversion.
        let base = u.floor().clamp(Vec3::splat(-1.0), max.as_vec3() + 1.0);
        let frac = (u - u.floor()).clamp(Vec3::ZERO, Vec3::ONE);
        let lo = base.as_ivec3();
        // The own cell is the corner nearest the position: floor((p − origin) / voxel_size).
        let own = IVec3::select(frac.cmpge(Vec3::splat(0.5)), IVec3::ONE, IVec3::ZERO);
        let own_cell = (lo + own).clamp(IVec3::ZERO, max).as_uvec3();
        let separated = self.separator(own_cell).unwrap_or(0);
        let grid = self.texels(face);
        let mut acc = Vec4::ZERO;
        for corner in 0..8 {
            let step = IVec3::new(corner & 1, (corner >> 1) & 1, (corner >> 2) & 1);
            if (0..3).any(|a| {
                step[a] != own[a]
                    && separated & (1 << Face::from_axis_sign(a, step[a] > own[a]).code()) != 0
            }) {
                continue;
            }
            let w = Vec3::select(step.cmpeq(IVec3::ONE), frac, Vec3::ONE - frac).element_product();
            if w == 0.0 {
                continue;
            }
            let t = (lo + step).clamp(IVec3::ZERO, max).as_uvec3();
            let i = t.x + self.dims.x * (t.y + self.dims.y * t.z);
            let texel = grid[i as usize].map(f16::to_f32);
            acc += w * Vec4::from_array(texel);
        }
        acc
    }
}

/// The separator grid of the module doc: per voxel, bit `f` set when the voxel and its
/// neighbour in direction `f` hold, between them, patches facing both ways along `f`'s axis.
fn separators(dims: UVec3, grids: &[Vec<Texel>; 6]) -> Vec<u8> {
    let count = grids[0].len();
    // Which faces have a patch, per voxel.
    let mut faces = vec![0u8; count];
    for (code, grid) in grids.iter().enumerate() {
        for (bits, texel) in faces.iter_mut().zip(grid) {
            if texel[3] != f16::ZERO {
                *bits |= 1 << code;
            }
        }
    }
    let mut out = vec![0u8; count];
    let strides = [1, dims.x as usize, (dims.x * dims.y) as usize];
    for z in 0..dims.z {
        for y in 0..dims.y {
            for x in 0..dims.x {
                let v = [x, y, z];
                let i = (x + dims.x * (y + dims.y * z)) as usize;
                for axis in 0..3 {
                    let both = 0b11u8 << (2 * axis);
                    // The neighbour on the positive side; the same pair seen from it is the
                    // negative side's.
                    if v[axis] + 1 >= dims[axis] {
                        continue;
                    }
                    let j = i + strides[axis];
                    if (faces[i] | faces[j]) & both == both {
                        out[i] |= 1 << (2 * axis);
                        out[j] |= 1 << (2 * axis + 1);
                    }
                }
            }
        }
    }
    out
}

/// The ambient-cube weights of a normal: its squared components over its squared length, so
/// they sum to 1. A zero or non-finite normal weighs the axes equally. [`Volume::sample`] no
/// longer blends the six directions this way (a surface patch holds its own surface's light, and
/// the other directions' grids other surfaces'); kept for tools that want the blend.
pub fn blend_weights(normal: Vec3) -> [f32; 3] {
    let sq = normal * normal;
    let len = sq.element_sum();
    if len > 0.0 && len.is_finite() {
        (sq / len).to_array()
    } else {
        [1.0 / 3.0; 3]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::PatchFace;

    fn layout(patches: Vec<PatchFace>) -> Layout {
        Layout::new(
            "test",
            Vec3::new(-1.0, 0.0, 2.0),
            0.5,
            UVec3::new(4, 3, 2),
            patches,
        )
        .unwrap()
    }

    fn patch(x: u32, y: u32, z: u32, face: Face) -> PatchFace {
        PatchFace {
            voxel: UVec3::new(x, y, z),
            face,
        }
    }

    /// Exactly representable in RGB9E5 and f16, so equality is exact.
    const VALUE: [f32; 3] = [1.5, 0.25, 3.0];

    fn frame(values: &[[f32; 3]]) -> Frame {
        Frame::encode(1, 1, values).unwrap()
    }

    #[test]
    fn a_patch_lands_on_its_texel_and_nowhere_else() {
        let l = layout(vec![patch(2, 1, 1, Face::NegY)]);
        let mut v = Volume::new(&l).unwrap();
        v.apply(&frame(&[VALUE])).unwrap();
        assert_eq!(v.frame().map(|h| h.patch_count), Some(1));
        let texel = (2 + 4 * (1 + 3)) as usize;
        for face in Face::ALL {
            let grid = v.texels(face);
            assert_eq!(grid.len(), 4 * 3 * 2);
            assert_eq!(v.texel_bytes(face).len(), 8 * grid.len());
            for (i, t) in grid.iter().enumerate() {
                let t = t.map(f16::to_f32);
                if face == Face::NegY && i == texel {
                    assert_eq!(t, [1.5, 0.25, 3.0, 1.0]);
                } else {
                    assert_eq!(t, [0.0; 4], "{face:?} texel {i}");
                }
            }
        }
        assert_eq!(
            v.texel(Face::NegY, UVec3::new(2, 1, 1))
                .map(|t| t.map(f16::to_f32)),
            Some([1.5, 0.25, 3.0, 1.0])
        );
        assert_eq!(v.texel(Face::NegY, UVec3::new(4, 1, 1)), None);
    }

    #[test]
    fn coverage_comes_from_the_layout_before_any_frame() {
        let l = layout(vec![patch(0, 0, 0, Face::PosX), patch(3, 2, 1, Face::PosX)]);
        let v = Volume::new(&l).unwrap();
        let covered: Vec<usize> = v
            .texels(Face::PosX)
            .iter()
            .enumerate()
            .filter(|(_, t)| t[3] == f16::ONE)
            .map(|(i, _)| i)
            .collect();
        assert_eq!(covered, vec![0, 4 * 3 * 2 - 1]);
        assert!(
            v.texels(Face::PosX)
                .iter()
                .all(|t| t[..3] == [f16::ZERO; 3])
        );
    }

    #[test]
    fn sampling_a_voxel_centre_along_the_face_normal_gives_the_patch() {
        let p = patch(1, 2, 0, Face::PosZ);
        let l = layout(vec![p, patch(1, 2, 0, Face::NegX)]);
        let mut v = Volume::new(&l).unwrap();
        v.apply(&frame(&[VALUE, [7.0, 7.0, 7.0]])).unwrap();
        let centre = l.voxel_center(p.voxel);
        assert_eq!(v.sample(centre, Vec3::Z), VALUE);
        assert_eq!(v.sample(centre, -Vec3::X), [7.0; 3]);
        // At the face itself half the filter reaches into the empty voxel in front; coverage
        // division takes that back out.
        assert_eq!(v.sample(l.patch_center(p), Vec3::Z), VALUE);
        // Facing away from both patches: nothing there.
        assert_eq!(v.sample(centre, -Vec3::Z), [0.0; 3]);
        assert_eq!(v.sample(centre, Vec3::X), [0.0; 3]);
        // A normal between the two reads the patch of the direction it faces most, and only
        // that one: the other belongs to another surface.
        assert_eq!(v.sample(centre, Vec3::new(-0.8, 0.0, 0.6)), [7.0; 3]);
        assert_eq!(v.sample(centre, Vec3::new(-0.6, 0.0, 0.8)), VALUE);
        // Ties go to X, then Y, as the bake's dominant face.
        assert_eq!(v.sample(centre, Vec3::new(-1.0, 0.0, 1.0)), [7.0; 3]);
        // A normal leaning into an empty direction still reads the face it faces most.
        assert_eq!(v.sample(centre, Vec3::new(0.0, 0.6, 0.8)), VALUE);
        assert_eq!(v.sample(centre, Vec3::new(0.0, 0.8, 0.6)), [0.0; 3]);
        // No side to read.
        assert_eq!(v.sample(centre, Vec3::ZERO), [0.0; 3]);
        assert_eq!(v.sample(centre, Vec3::NAN), [0.0; 3]);
    }

    /// Two rooms side by side along X, their floors (+Y) in voxels x = 0..=1 and 2..=3 of the
    /// layout's row y = 1, z = 0, and a wall between voxels 1 and 2 thinner than two voxels:
    /// its two sides face −X (into the left room) and +X (into the right one).
    fn two_rooms(wall: [(u32, Face); 2]) -> Volume {
        let mut patches: Vec<PatchFace> = (0..4).map(|x| patch(x, 1, 0, Face::PosY)).collect();
        patches.extend(wall.iter().map(|&(x, f)| patch(x, 1, 0, f)));
        let mut v = Volume::new(&layout(patches)).unwrap();
        let left = [1.0, 2.0, 4.0];
        v.apply(&frame(&[left, left, [0.0; 3], [0.0; 3], VALUE, VALUE]))
            .unwrap();
        v
    }

    #[test]
    fn light_is_not_interpolated_through_a_thin_wall() {
        let l = layout(vec![]);
        let right_floor = |x: f32| l.origin() + Vec3::new(x, 0.75, 0.25);
        // The wall's sides in the voxels either side of the plane between them, or both in one
        // voxel: either way the floor right of the wall reads none of the left room's light.
        for wall in [
            [(1, Face::NegX), (2, Face::PosX)],
            [(1, Face::NegX), (1, Face::PosX)],
            [(2, Face::NegX), (2, Face::PosX)],
        ] {
            let v = two_rooms(wall);
            for x in [1.0, 1.01, 1.1, 1.25, 1.4, 1.5, 1.75] {
                // Voxel 2's floor (x from 1.0 to 1.5) lies right of the wall unless the wall is
                // inside voxel 2; voxel 3's always does.
                if wall[0].0 == 2 && x < 1.5 {
                    continue;
                }
                assert_eq!(
                    v.sample(right_floor(x), Vec3::Y),
                    [0.0; 3],
                    "{wall:?} at {x}"
                );
            }
            let bits = v.separator(UVec3::new(1, 1, 0)).unwrap();
            // Voxel 1 is separated from voxel 2 in every case, and from voxel 0 when it holds
            // both sides itself.
            let both_in_1 = wall.iter().all(|w| w.0 == 1);
            assert_eq!(bits & 0b11, if both_in_1 { 0b11 } else { 0b01 }, "{wall:?}");
        }
        // Without the wall the floor interpolates across the same plane.
        let mut v = Volume::new(&layout(
            (0..4).map(|x| patch(x, 1, 0, Face::PosY)).collect(),
        ))
        .unwrap();
        v.apply(&frame(&[[4.0; 3], [4.0; 3], [0.0; 3], [0.0; 3]]))
            .unwrap();
        assert_eq!(v.sample(right_floor(1.0), Vec3::Y), [2.0; 3]);
        // 1.1 is 0.7 of the way from voxel 1's centre (0.75) to voxel 2's (1.25): 4 · 0.3.
        let got = v.sample(right_floor(1.1), Vec3::Y);
        assert!(got.iter().all(|&c| (c - 1.2).abs() < 1e-5), "{got:?}");
        assert!(v.separators().iter().all(|&b| b == 0));
    }

    #[test]
    fn one_sided_neighbours_are_not_separators() {
        // A box's side facing +X next to a floor: only one direction along X, so no wall.
        let l = layout(vec![
            patch(1, 1, 0, Face::PosY),
            patch(2, 1, 0, Face::PosY),
            patch(2, 1, 0, Face::PosX),
        ]);
        let v = Volume::new(&l).unwrap();
        assert!(v.separators().iter().all(|&b| b == 0));
        // A wall a voxel thick: its sides in neighbouring voxels, facing both ways.
        let l = layout(vec![patch(1, 0, 1, Face::NegZ), patch(1, 0, 0, Face::PosZ)]);
        let v = Volume::new(&l).unwrap();
        assert_eq!(
            v.separator(UVec3::new(1, 0, 0)),
            Some(1 << Face::PosZ.code())
        );
        assert_eq!(
            v.separator(UVec3::new(1, 0, 1)),
            Some(1 << Face::NegZ.code())
        );
        assert_eq!(v.separator(UVec3::new(0, 0, 0)), Some(0));
        assert_eq!(v.separator(UVec3::new(4, 0, 0)), None);
    }

    #[test]
    fn neighbouring_patches_interpolate_and_empty_neighbours_drop_out() {
        let l = layout(vec![patch(0, 1, 0, Face::PosY), patch(1, 1, 0, Face::PosY)]);
        let mut v = Volume::new(&l).unwrap();
        v.apply(&frame(&[[1.0; 3], [3.0; 3]])).unwrap();
        let a = l.voxel_center(UVec3::new(0, 1, 0));
        let b = l.voxel_center(UVec3::new(1, 1, 0));
        let mid = v.sample((a + b) / 2.0, Vec3::Y);
        assert_eq!(mid, [2.0; 3]);
        // Halfway towards the empty z = 1 row: same value, not half of it.
        let off = a + Vec3::new(0.0, 0.0, 0.25);
        assert_eq!(v.sample(off, Vec3::Y), [1.0; 3]);
        // Far outside the grid the edge texels repeat, and nothing overflows.
        assert_eq!(v.sample(a - Vec3::X * 100.0, Vec3::Y), [1.0; 3]);
        assert_eq!(v.sample(Vec3::splat(1e30), Vec3::Y), [0.0; 3]);
        assert_eq!(v.sample(Vec3::splat(f32::NAN), Vec3::Y), [0.0; 3]);
    }

    #[test]
    fn blend_weights_sum_to_one() {
        for n in [
            Vec3::X,
            Vec3::new(1.0, 2.0, 3.0),
            Vec3::new(-0.3, 0.9, -0.1),
            Vec3::new(1e-20, 0.0, 0.0),
            Vec3::new(1e20, -1e20, 1e20),
            Vec3::ZERO,
            Vec3::NAN,
        ] {
            let w = blend_weights(n);
            let sum: f32 = w.iter().sum();
            assert!((sum - 1.0).abs() < 1e-6, "{n:?}: {w:?}");
            assert!(w.iter().all(|&x| (0.0..=1.0).contains(&x)), "{n:?}: {w:?}");
        }
        assert_eq!(blend_weights(Vec3::new(0.0, -2.0, 0.0)), [0.0, 1.0, 0.0]);
        let w = blend_weights(Vec3::new(3.0, 0.0, 4.0));
        assert!((w[0] - 0.36).abs() < 1e-6 && (w[2] - 0.64).abs() < 1e-6);
    }

    #[test]
    fn a_frame_with_the_wrong_patch_count_is_refused() {
        let l = layout(vec![patch(0, 0, 0, Face::PosX)]);
        let mut v = Volume::new(&l).unwrap();
        let err = v.apply(&frame(&[VALUE, VALUE])).unwrap_err();
        assert_eq!(
            err,
            VolumeError::PatchCount {
                frame: 2,
                layout: 1
            }
        );
        assert!(err.to_string().contains("2 patches"));
        assert_eq!(
            v.apply_irradiance(&[]),
            Err(VolumeError::PatchCount {
                frame: 0,
                layout: 1
            })
        );
        // Nothing was written.
        assert_eq!(v.frame(), None);
        assert_eq!(v.texels(Face::PosX)[0][0], f16::ZERO);
    }

    #[test]
    fn bright_values_stay_finite_in_f16() {
        let l = layout(vec![patch(0, 0, 0, Face::PosX)]);
        let mut v = Volume::new(&l).unwrap();
        v.apply(&frame(&[[1e9, 0.0, 65408.0]])).unwrap();
        let t = v.texels(Face::PosX)[0].map(f16::to_f32);
        assert!(t.iter().all(|x| x.is_finite()), "{t:?}");
        assert_eq!(t[2], 65408.0);
        assert_eq!(v.flags(), FLAG_CLAMPED, "the server's clamp shows");
    }

    /// In-process irradiance (a viewer relighting without a server) meets f16's own limit:
    /// clamped to f16's largest and flagged, never infinity or NaN in the texture.
    #[test]
    fn in_process_values_past_f16_are_clamped_and_flagged() {
        let l = layout(vec![patch(0, 0, 0, Face::PosX), patch(1, 0, 0, Face::PosX)]);
        let mut v = Volume::new(&l).unwrap();
        let texels = |v: &Volume| -> Vec<[f32; 4]> {
            [0, 1]
                .map(|x| {
                    v.texel(Face::PosX, UVec3::new(x, 0, 0))
                        .unwrap()
                        .map(f16::to_f32)
                })
                .to_vec()
        };
        v.apply_irradiance(&[[1e9, 65504.0, 1.5], [0.25, f32::MAX, 0.0]])
            .unwrap();
        assert_eq!(v.flags(), FLAG_CLAMPED);
        assert_eq!(
            texels(&v),
            [[65504.0, 65504.0, 1.5, 1.0], [0.25, 65504.0, 0.0, 1.0]]
        );
        v.apply_irradiance(&[[f32::INFINITY, f32::NAN, -1e-7], [1e6, 2.0, 3.0]])
            .unwrap();
        assert_eq!(v.flags(), FLAG_NON_FINITE | FLAG_CLAMPED);
        assert_eq!(
            texels(&v),
            [[65504.0, 0.0, 0.0, 1.0], [65504.0, 2.0, 3.0, 1.0]]
        );
        v.apply_irradiance(&[VALUE, VALUE]).unwrap();
        assert_eq!(v.flags(), 0);
        assert!(texels(&v).iter().flatten().all(|x| x.is_finite()));
    }

    #[test]
    fn grids_too_large_for_a_texture_are_refused() {
        let big = |dims| Layout::new("big", Vec3::ZERO, 1.0, dims, vec![]).unwrap();
        assert!(matches!(
            Volume::new(&big(UVec3::new(4096, 1, 1))),
            Err(VolumeError::TooLarge { .. })
        ));
        assert!(matches!(
            Volume::new(&big(UVec3::new(2048, 2048, 8))),
            Err(VolumeError::TooLarge { .. })
        ));
    }
}
