//! A scene's patch layout as it goes on the wire: the one conversion from the bake's patches to
//! the proto [`Layout`](crate::proto::Layout). gRPC sends it as it is, HTTP as JSON with the same
//! fields, and a viewer that holds the baked file reads it back as a server would send it.

use bounce_types::face::Face;

use crate::proto;

/// The layout of `scene`: patch `i` of every frame is the `i`-th of `patches` (its voxel and the
/// face of that voxel it stands for); probe `k` of every probe frame is at `probes[k]`.
pub fn to_proto(
    scene: &str,
    origin: [f32; 3],
    voxel_size: f32,
    dims: [u32; 3],
    patches: impl ExactSizeIterator<Item = ([u32; 3], Face)> + Clone,
    probes: &[[f32; 3]],
) -> proto::Layout {
    proto::Layout {
        scene: scene.to_owned(),
        origin: origin.to_vec(),
        voxel_size,
        dims: dims.to_vec(),
        // A count past `u32` cannot be valid: the client checks it against the voxel list.
        patch_count: u32::try_from(patches.len()).unwrap_or(u32::MAX),
        voxels: patches.clone().flat_map(|(voxel, _)| voxel).collect(),
        // The proto enum's numbers are the face codes.
        faces: patches.map(|(_, face)| i32::from(face.code())).collect(),
        probe_positions: probes.iter().flatten().copied().collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patches_keep_their_order_and_faces_their_codes() {
        let patches = [([1, 2, 3], Face::NegY), ([0, 0, 1], Face::PosZ)];
        let l = to_proto(
            "box",
            [0.5, 0.0, -1.0],
            0.25,
            [4, 4, 4],
            patches.into_iter(),
            &[[1.0, 2.0, 3.0]],
        );
        assert_eq!(l.scene, "box");
        assert_eq!(l.patch_count, 2);
        assert_eq!(l.voxels, vec![1, 2, 3, 0, 0, 1]);
        assert_eq!(
            l.faces,
            vec![i32::from(Face::NegY.code()), i32::from(Face::PosZ.code())]
        );
        assert_eq!(l.origin, vec![0.5, 0.0, -1.0]);
        assert_eq!(l.dims, vec![4, 4, 4]);
        assert_eq!(l.probe_positions, vec![1.0, 2.0, 3.0]);
    }
}
