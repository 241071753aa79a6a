//! A scene's patch layout as a server describes it (the proto `Layout`, or the same fields as
//! JSON over HTTP), checked before anything indexes with it.
//!
//! A server's answer is input like any other: a layout whose voxels lie outside its grid, whose
//! face codes are unknown, whose arrays disagree in length or that puts two patches on one voxel
//! face would make a volume write out of bounds or silently overwrite a patch, so each is
//! refused here with the patch and field named.

use std::collections::HashMap;

use bounce_wire::proto;
use glam::{UVec3, Vec3};
use serde::Deserialize;
use thiserror::Error;

pub use bounce_types::face::Face;

/// Largest voxel count along one axis a layout may claim. Far beyond any real bake (grids of
/// 2^28 voxels are the largest the baker walks), and small enough that products of three never
/// overflow a `u64`.
pub const MAX_DIM: u32 = 1 << 16;

/// One patch: a face of one voxel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct PatchFace {
    pub voxel: UVec3,
    pub face: Face,
}

/// A validated layout: patch `i` of every frame of this scene is `patches()[i]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    scene: String,
    origin: Vec3,
    voxel_size: f32,
    dims: UVec3,
    patches: Vec<PatchFace>,
    /// Where the scene's irradiance probes are: probe `k` of every probe frame (six values,
    /// one a face direction, from `6 · k`). Empty for a scene without probes.
    probes: Vec<Vec3>,
}

#[derive(Debug, Clone, PartialEq, Error)]
pub enum LayoutError {
    #[error("layout is not valid JSON: {0}")]
    Json(String),
    #[error("layout origin: expected 3 finite numbers, got {0:?}")]
    Origin(Vec<f32>),
    #[error("layout voxel_size: must be finite and positive (got {0})")]
    VoxelSize(f32),
    #[error("layout dims: expected 3 voxel counts, each 1..={MAX_DIM}, got {0:?}")]
    Dims(Vec<u32>),
    #[error("layout {field}: {got} entries for {patch_count} patches (expected {expected})")]
    Length {
        field: &'static str,
        patch_count: u64,
        expected: u64,
        got: usize,
    },
    #[error("layout patch {patch}: voxel {voxel:?} is outside the {dims:?} grid")]
    VoxelOutside {
        patch: usize,
        voxel: [u32; 3],
        dims: [u32; 3],
    },
    #[error("layout patch {patch}: face {found} is not a face code (0..=5)")]
    Face { patch: usize, found: String },
    #[error("layout patch {patch}: face {face:?} of voxel {voxel:?} is already patch {first}")]
    Duplicate {
        patch: usize,
        first: usize,
        voxel: [u32; 3],
        face: Face,
    },
    #[error("layout probe_positions: {0}")]
    Probes(String),
}

impl Layout {
    /// Checks a layout given as typed values.
    pub fn new(
        scene: impl Into<String>,
        origin: Vec3,
        voxel_size: f32,
        dims: UVec3,
        patches: Vec<PatchFace>,
    ) -> Result<Layout, LayoutError> {
        if !origin.is_finite() {
            return Err(LayoutError::Origin(origin.to_array().to_vec()));
        }
        if !(voxel_size.is_finite() && voxel_size > 0.0) {
            return Err(LayoutError::VoxelSize(voxel_size));
        }
        if dims.cmpeq(UVec3::ZERO).any() || dims.cmpgt(UVec3::splat(MAX_DIM)).any() {
            return Err(LayoutError::Dims(dims.to_array().to_vec()));
        }
        let mut seen: HashMap<PatchFace, usize> = HashMap::with_capacity(patches.len());
        for (i, p) in patches.iter().enumerate() {
            if p.voxel.cmpge(dims).any() {
                return Err(LayoutError::VoxelOutside {
                    patch: i,
                    voxel: p.voxel.to_array(),
                    dims: dims.to_array(),
                });
            }
            if let Some(&first) = seen.get(p) {
                return Err(LayoutError::Duplicate {
                    patch: i,
                    first,
                    voxel: p.voxel.to_array(),
                    face: p.face,
                });
            }
            seen.insert(*p, i);
        }
        Ok(Layout {
            scene: scene.into(),
            origin,
            voxel_size,
            dims,
            patches,
            probes: Vec::new(),
        })
    }

    /// This layout with its probes, from the wire's flat `x, y, z` list.
    pub fn with_probes(mut self, flat: &[f32]) -> Result<Layout, LayoutError> {
        if !flat.len().is_multiple_of(3) {
            return Err(LayoutError::Probes(format!(
                "{} numbers, not three a probe",
                flat.len()
            )));
        }
        if let Some(i) = flat.iter().position(|v| !v.is_finite()) {
            return Err(LayoutError::Probes(format!(
                "probe {}'s position is not finite",
                i / 3
            )));
        }
        self.probes = flat
            .chunks_exact(3)
            .map(|p| Vec3::new(p[0], p[1], p[2]))
            .collect();
        Ok(self)
    }

    /// Where the scene's irradiance probes are, in the order of the probe frames.
    pub fn probes(&self) -> &[Vec3] {
        &self.probes
    }

    /// From the gRPC answer.
    pub fn from_proto(l: &proto::Layout) -> Result<Layout, LayoutError> {
        let faces = l.faces.iter().map(|&f| WireFace::Code(i64::from(f)));
        Layout::from_wire(
            &l.scene,
            &l.origin,
            l.voxel_size,
            &l.dims,
            u64::from(l.patch_count),
            &l.voxels,
            faces,
        )?
        .with_probes(&l.probe_positions)
    }

    /// From `GET /v1/scenes/{name}/layout`: the proto's fields as JSON, faces as codes or as the
    /// proto enum's names. Fields this client does not know are ignored, so a server may add some.
    pub fn from_json(json: &[u8]) -> Result<Layout, LayoutError> {
        let w: JsonLayout =
            serde_json::from_slice(json).map_err(|e| LayoutError::Json(e.to_string()))?;
        Layout::from_wire(
            &w.scene,
            &w.origin,
            w.voxel_size,
            &w.dims,
            w.patch_count,
            &w.voxels,
            w.faces.into_iter(),
        )?
        .with_probes(&w.probe_positions)
    }

    fn from_wire(
        scene: &str,
        origin: &[f32],
        voxel_size: f32,
        dims: &[u32],
        patch_count: u64,
        voxels: &[u32],
        faces: impl ExactSizeIterator<Item = WireFace>,
    ) -> Result<Layout, LayoutError> {
        let origin =
            <[f32; 3]>::try_from(origin).map_err(|_| LayoutError::Origin(origin.into()))?;
        let dims_arr = <[u32; 3]>::try_from(dims).map_err(|_| LayoutError::Dims(dims.into()))?;
        // Lengths before anything is allocated for the patches: `patch_count` is the server's
        // claim, the arrays are what it actually sent.
        let length = |field, expected: u64, got: usize| {
            if got as u64 == expected {
                Ok(())
            } else {
                Err(LayoutError::Length {
                    field,
                    patch_count,
                    expected,
                    got,
                })
            }
        };
        length("voxels", patch_count.saturating_mul(3), voxels.len())?;
        length("faces", patch_count, faces.len())?;
        let patches = voxels
            .chunks_exact(3)
            .zip(faces)
            .enumerate()
            .map(|(i, (v, f))| {
                Ok(PatchFace {
                    voxel: UVec3::new(v[0], v[1], v[2]),
                    face: f.face(i)?,
                })
            })
            .collect::<Result<Vec<_>, LayoutError>>()?;
        Layout::new(
            scene,
            Vec3::from_array(origin),
            voxel_size,
            UVec3::from_array(dims_arr),
            patches,
        )
    }

    /// The scene's name, as the server calls it.
    pub fn scene(&self) -> &str {
        &self.scene
    }

    /// World position of the grid's minimum corner.
    pub fn origin(&self) -> Vec3 {
        self.origin
    }

    pub fn voxel_size(&self) -> f32 {
        self.voxel_size
    }

    /// Voxel counts along X, Y, Z; each at least 1.
    pub fn dims(&self) -> UVec3 {
        self.dims
    }

    pub fn patches(&self) -> &[PatchFace] {
        &self.patches
    }

    pub fn patch_count(&self) -> usize {
        self.patches.len()
    }

    /// World position of a voxel's centre.
    pub fn voxel_center(&self, voxel: UVec3) -> Vec3 {
        self.origin + (voxel.as_vec3() + 0.5) * self.voxel_size
    }

    /// World position of a patch's centre: the middle of its voxel face.
    pub fn patch_center(&self, patch: PatchFace) -> Vec3 {
        self.voxel_center(patch.voxel) + patch.face.normal() * (0.5 * self.voxel_size)
    }
}

#[derive(Deserialize)]
struct JsonLayout {
    #[serde(default)]
    scene: String,
    origin: Vec<f32>,
    voxel_size: f32,
    dims: Vec<u32>,
    patch_count: u64,
    voxels: Vec<u32>,
    faces: Vec<WireFace>,
    /// Absent from servers before probes.
    #[serde(default)]
    probe_positions: Vec<f32>,
}

/// A face as a wire carries it: the code, or (proto JSON mapping) the enum value's name.
#[derive(Deserialize)]
#[serde(untagged)]
enum WireFace {
    Code(i64),
    Name(String),
}

impl WireFace {
    fn face(self, patch: usize) -> Result<Face, LayoutError> {
        let code = match &self {
            WireFace::Code(c) => u8::try_from(*c).ok(),
            WireFace::Name(n) => FACE_NAMES.iter().position(|&m| m == n).map(|c| c as u8),
        };
        code.and_then(Face::from_code)
            .ok_or_else(|| LayoutError::Face {
                patch,
                found: match self {
                    WireFace::Code(c) => c.to_string(),
                    WireFace::Name(n) => format!("{n:?}"),
                },
            })
    }
}

/// The proto enum's value names, in code order.
const FACE_NAMES: [&str; 6] = [
    "FACE_POS_X",
    "FACE_NEG_X",
    "FACE_POS_Y",
    "FACE_NEG_Y",
    "FACE_POS_Z",
    "FACE_NEG_Z",
];

#[cfg(test)]
mod tests {
    use super::*;

    fn proto_layout() -> proto::Layout {
        proto::Layout {
            scene: "box".into(),
            origin: vec![-1.0, 0.0, -1.0],
            voxel_size: 0.5,
            dims: vec![4, 4, 4],
            patch_count: 3,
            voxels: vec![0, 0, 0, 0, 0, 0, 3, 3, 3],
            faces: vec![0, 2, 5],
            probe_positions: vec![],
        }
    }

    #[test]
    fn probes_read_from_both_wires_and_are_checked() {
        let mut p = proto_layout();
        p.probe_positions = vec![0.5, 1.0, 1.5, -0.5, 0.0, 0.25];
        let l = Layout::from_proto(&p).unwrap();
        assert_eq!(
            l.probes(),
            &[Vec3::new(0.5, 1.0, 1.5), Vec3::new(-0.5, 0.0, 0.25)]
        );
        let json = br#"{"scene":"box","origin":[-1,0,-1],"voxel_size":0.5,"dims":[4,4,4],
            "patch_count":3,"voxels":[0,0,0,0,0,0,3,3,3],"faces":[0,2,5],
            "probe_positions":[0.5,1,1.5,-0.5,0,0.25]}"#;
        assert_eq!(Layout::from_json(json).unwrap(), l);
        // A server from before probes sends none.
        assert!(
            Layout::from_proto(&proto_layout())
                .unwrap()
                .probes()
                .is_empty()
        );
        refused(|l| l.probe_positions = vec![1.0, 2.0], "probe_positions");
        refused(
            |l| l.probe_positions = vec![1.0, f32::INFINITY, 0.0],
            "not finite",
        );
    }

    #[test]
    fn a_good_layout_reads() {
        let l = Layout::from_proto(&proto_layout()).unwrap();
        assert_eq!(l.scene(), "box");
        assert_eq!(l.dims(), UVec3::splat(4));
        assert_eq!(l.patch_count(), 3);
        assert_eq!(
            l.patches()[2],
            PatchFace {
                voxel: UVec3::splat(3),
                face: Face::NegZ
            }
        );
        assert_eq!(l.voxel_center(UVec3::ZERO), Vec3::new(-0.75, 0.25, -0.75));
        assert_eq!(l.patch_center(l.patches()[0]), Vec3::new(-0.5, 0.25, -0.75));
    }

    #[test]
    fn json_reads_codes_and_names_and_ignores_new_fields() {
        let json = br#"{"scene":"box","origin":[-1,0,-1],"voxel_size":0.5,"dims":[4,4,4],
            "patch_count":3,"voxels":[0,0,0,0,0,0,3,3,3],"faces":[0,"FACE_POS_Y",5],"extra":1}"#;
        let l = Layout::from_json(json).unwrap();
        assert_eq!(l, Layout::from_proto(&proto_layout()).unwrap());
        assert!(matches!(
            Layout::from_json(b"{\"scene\":"),
            Err(LayoutError::Json(_))
        ));
    }

    #[track_caller]
    fn refused(edit: impl FnOnce(&mut proto::Layout), want: &str) {
        let mut l = proto_layout();
        edit(&mut l);
        let err = Layout::from_proto(&l).expect_err("must be refused");
        assert!(err.to_string().contains(want), "{err} lacks {want:?}");
    }

    #[test]
    fn hostile_layouts_are_refused_with_the_field_named() {
        refused(|l| l.dims = vec![4, 0, 4], "dims");
        refused(|l| l.dims = vec![4, 4], "dims");
        refused(|l| l.dims = vec![4, 4, MAX_DIM + 1], "dims");
        refused(|l| l.origin = vec![0.0, f32::NAN, 0.0], "origin");
        refused(|l| l.origin = vec![], "origin");
        refused(|l| l.voxel_size = 0.0, "voxel_size");
        refused(|l| l.voxel_size = f32::INFINITY, "voxel_size");
        refused(|l| l.voxels[8] = 4, "patch 2: voxel [3, 3, 4] is outside");
        refused(|l| l.faces[1] = 6, "patch 1: face 6");
        refused(|l| l.faces[1] = -1, "patch 1: face -1");
        refused(
            |l| l.faces[1] = 0,
            "patch 1: face PosX of voxel [0, 0, 0] is already patch 0",
        );
        refused(|l| l.patch_count = 4, "voxels: 9 entries for 4 patches");
        refused(|l| l.patch_count = u32::MAX, "voxels");
        refused(
            |l| {
                l.faces.pop();
            },
            "faces: 2 entries",
        );
        refused(|l| l.voxels.push(0), "voxels: 10 entries");
    }

    #[test]
    fn an_empty_layout_is_valid() {
        let mut l = proto_layout();
        l.patch_count = 0;
        l.voxels.clear();
        l.faces.clear();
        assert_eq!(Layout::from_proto(&l).unwrap().patch_count(), 0);
    }
}
