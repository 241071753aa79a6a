//! What holding each element's source constant costs: the first bounce gathered with `B0`
//! evaluated where every form-factor ray lands.
//!
//! The transport assumes an element's exitance `B0` is uniform over it (docs/design.md §1). Under
//! a light close to the surfaces or across a sharp shadow it is not, and a receiver next to one
//! part of a source element gathers that part's light, not the element's mean. This module
//! measures that error directly: it retraces each transport row's form-factor rays (same seed,
//! same count, so the same rays as `F`) and, at every landing, takes that point's own `B0` (its
//! triangle's emission and albedo, direct light with one shadow ray from it) and, beside it, the
//! mean `B0` of the element it landed on. The second sum is `F · B0` exactly; the difference is
//! the source's share of the method error (`bounce verify`). A diagnostic: it costs a closest-hit
//! and a shadow ray per form-factor ray, far more than a relight, and nothing serves it.

use std::sync::Arc;

use glam::Vec3;
use rayon::prelude::*;

use crate::direct::{PreparedLight, ShadowCache, surface_irradiance};
use crate::light::LightSet;
use crate::patch::PatchLayout;
use crate::scene::Scene;
use crate::surface::{SamplePoint, SurfaceScene, scene_mesh};
use crate::voxel::Pieces;

/// Per transport row, the first bounce gathered by its form-factor rays.
#[derive(Debug, Clone, PartialEq)]
pub struct FirstBounce {
    /// `B0` where each ray landed.
    pub pointwise: Vec<[f32; 3]>,
    /// `B0` of the element each ray landed on (`F · B0`).
    pub element: Vec<[f32; 3]>,
}

/// The first bounce of every row of `rows` (the transport's rows, with their `pieces`), under
/// `lights`, with `element_b0` (per row: `L_e + ρ ⊙ E_direct`, as a relight computes it) for
/// the element-constant sum. `rays` and `seed` must be the bake's, for the rays to be `F`'s.
pub fn first_bounce(
    scene: &Scene,
    rows: &PatchLayout,
    pieces: &Pieces,
    lights: &LightSet,
    element_b0: &[[f32; 3]],
    rays: u32,
    seed: u64,
) -> FirstBounce {
    assert_eq!(element_b0.len(), rows.len(), "one B0 per transport row");
    let mesh = Arc::new(scene_mesh(scene));
    let prepared: Vec<PreparedLight> = lights
        .lights
        .iter()
        .filter_map(PreparedLight::new)
        .collect();
    let tracer = SurfaceScene::new(scene, mesh.clone(), rows, pieces);
    let per_row: Vec<([f32; 3], [f32; 3])> = (0..rows.len())
        .into_par_iter()
        .map_init(
            || ShadowCache::new(prepared.len()),
            |cache, i| {
                let (mut pointwise, mut element) = (Vec3::ZERO, Vec3::ZERO);
                for k in 0..rays {
                    let Some(l) = tracer.landing(i, k, seed) else {
                        continue;
                    };
                    let t = &scene.triangles[l.triangle as usize];
                    let at = SamplePoint {
                        position: l.position.to_array(),
                        normal: l.normal.to_array(),
                    };
                    let e = Vec3::from(surface_irradiance(&mesh, &[at], &prepared, cache));
                    pointwise += t.emission + t.albedo * e;
                    element += Vec3::from(element_b0[l.row]);
                }
                let r = rays.max(1) as f32;
                ((pointwise / r).to_array(), (element / r).to_array())
            },
        )
        .collect();
    FirstBounce {
        pointwise: per_row.iter().map(|p| p.0).collect(),
        element: per_row.iter().map(|p| p.1).collect(),
    }
}
