//! The six face directions of a voxel: how a patch faces, on disk, on the wire and in the
//! clients' six-direction volume.

use glam::Vec3;
use serde::{Deserialize, Serialize};

/// The six face directions of a voxel. The discriminant is the on-disk and on-wire code.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[repr(u8)]
pub enum Face {
    PosX = 0,
    NegX = 1,
    PosY = 2,
    NegY = 3,
    PosZ = 4,
    NegZ = 5,
}

impl Face {
    pub const ALL: [Face; 6] = [
        Face::PosX,
        Face::NegX,
        Face::PosY,
        Face::NegY,
        Face::PosZ,
        Face::NegZ,
    ];

    pub fn from_code(code: u8) -> Option<Face> {
        Face::ALL.get(code as usize).copied()
    }

    pub fn code(self) -> u8 {
        self as u8
    }

    /// 0 for X, 1 for Y, 2 for Z.
    pub fn axis(self) -> usize {
        self as usize / 2
    }

    /// +1 for the positive faces, −1 for the negative ones.
    pub fn sign(self) -> f32 {
        if (self as u8).is_multiple_of(2) {
            1.0
        } else {
            -1.0
        }
    }

    pub fn normal(self) -> Vec3 {
        let mut n = Vec3::ZERO;
        n[self.axis()] = self.sign();
        n
    }

    pub fn from_axis_sign(axis: usize, positive: bool) -> Face {
        Face::ALL[axis * 2 + usize::from(!positive)]
    }
}

/// The face direction a surface with unit normal `n` faces most: the axis of its largest
/// component (the lower axis on a tie), signed as that component.
pub fn dominant_face(n: Vec3) -> Face {
    let a = n.abs();
    let axis = if a.x >= a.y && a.x >= a.z {
        0
    } else if a.y >= a.z {
        1
    } else {
        2
    };
    Face::from_axis_sign(axis, n[axis] >= 0.0)
}
