//! Where a row's near-field rays landed ([`crate::nearfield`]), as the bake gathers them: per
//! sample point, the share of the row's rays and the mean albedo of what they met. Shared by the
//! form factors' pass ([`crate::formfactor::NearRays`]) and its retrace twin
//! ([`crate::nearfield::near_field_rows`]), which must agree bit for bit; it imports neither.

use glam::Vec3;

/// Where one row's near rays landed that one sample point stands for: an entry of the
/// near-field matrix as the bake finds it ([`crate::nearfield::NearField::from_landings`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Landings {
    /// The sample point (column).
    pub sample: u32,
    /// The share of the row's rays.
    pub share: f32,
    /// The mean albedo of the triangles they landed on, each channel rounded to f16.
    pub albedo: [f32; 3],
}

/// A row's entries from its near rays' landings, in ray order: per landing, the sample point it
/// went to and the albedo of the triangle it met. Sorted stably by sample, so the albedos sum in
/// ray order and the form factors' pass and the retrace get the same bits; `hits` is left
/// sorted.
pub(crate) fn landings_of(hits: &mut [(u32, Vec3)], rays: u32) -> Vec<Landings> {
    hits.sort_by_key(|h| h.0);
    let mut row: Vec<(u32, u32, Vec3)> = Vec::new();
    for &(q, albedo) in hits.iter() {
        match row.last_mut() {
            Some((c, count, sum)) if *c == q => {
                *count += 1;
                *sum += albedo;
            }
            _ => row.push((q, 1, albedo)),
        }
    }
    let inv = 1.0 / rays as f32;
    row.into_iter()
        .map(|(sample, count, sum)| Landings {
            sample,
            share: count as f32 * inv,
            albedo: (sum / count as f32)
                .to_array()
                .map(|a| half::f16::from_f32(a).to_f32()),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn landings_of_sums_each_samples_albedo_in_ray_order() {
        let mut hits = vec![
            (5, Vec3::splat(0.2)),
            (1, Vec3::new(1.0, 0.0, 0.0)),
            (5, Vec3::splat(0.4)),
            (1, Vec3::new(0.0, 1.0, 0.0)),
            (5, Vec3::splat(0.6)),
        ];
        let row = landings_of(&mut hits, 10);
        assert_eq!(row.len(), 2);
        assert_eq!((row[0].sample, row[0].share), (1, 0.2));
        assert_eq!(row[0].albedo, [0.5, 0.5, 0.0]);
        assert_eq!((row[1].sample, row[1].share), (5, 0.3));
        // Rounded to f16, as the file keeps it.
        let f16 = |x: f32| half::f16::from_f32(x).to_f32();
        assert_eq!(row[1].albedo, [f16((0.2 + 0.4 + 0.6) / 3.0); 3]);
        assert!(landings_of(&mut [], 10).is_empty());
    }
}
