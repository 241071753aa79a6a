//! Environment maps to a sky: an equirectangular HDR image (Radiance `.hdr` or OpenEXR) projected
//! onto the order-2 spherical harmonics a sky light is given in ([`bounce_types::sh`]).
//!
//! The image's mapping is three.js's `equirectUv` (and so Blender's and most HDR sites'): pixel
//! column `u` (0 at the left edge, 1 at the right) is the longitude `φ = 2π (u − ½)`, row `v` (0 at
//! the top) the angle from straight up `θ = π v`, and the direction is
//! `(sin θ cos φ, cos θ, sin θ sin φ)` in the scene's axes (glTF's +Y up): the image's middle
//! looks along +X, its top row is the zenith.
//!
//! Each pixel is a patch of the sphere of solid angle `(2π / W)(π / H) sin θ` at its centre, so
//!
//! ```text
//! L_lm = Σ_pixels L(ω_p) Y_lm(ω_p) ΔΩ_p
//! ```
//!
//! summed in f64. Order 2 keeps only the low frequencies: a sun in the image becomes a broad bright
//! lobe, not a sharp light (give a sun as a directional light, with shadows, beside the sky).
//! What this does not do: rotate the map (turn the scene, or the coefficients, instead), or read
//! an image's exposure or white balance metadata (its values are taken as radiance).

use bounce_types::sh::{SH_COEFFICIENTS, sh_basis};

/// The largest image accepted, per side: a 16k-wide map is more than order 2 can use.
pub const MAX_SIDE: u32 = 16_384;
/// The largest image accepted, in pixels (a 8192 × 4096 map).
pub const MAX_PIXELS: u64 = 1 << 25;

/// Why an image gives no sky.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EnvironmentError {
    #[error("not an image this build reads ({0}); give a Radiance .hdr or an OpenEXR file")]
    Format(String),
    #[error("a {width} × {height} image: more than {MAX_SIDE} a side or {MAX_PIXELS} pixels")]
    TooLarge { width: u32, height: u32 },
    #[error("an empty image ({width} × {height})")]
    Empty { width: u32, height: u32 },
    #[error("pixel ({x}, {y}) is {value:?}: radiance must be finite and not negative")]
    BadPixel { x: u32, y: u32, value: [f32; 3] },
    #[error("{pixels} pixels for a {width} × {height} image")]
    Size {
        width: u32,
        height: u32,
        pixels: usize,
    },
}

/// The SH coefficients of an equirectangular map of `width × height` linear RGB radiance
/// values, row by row from the top (the module doc's mapping).
pub fn project_equirect(
    width: u32,
    height: u32,
    pixels: &[[f32; 3]],
) -> Result<[[f32; 3]; SH_COEFFICIENTS], EnvironmentError> {
    if width == 0 || height == 0 {
        return Err(EnvironmentError::Empty { width, height });
    }
    check_size(width, height)?;
    if pixels.len() as u64 != u64::from(width) * u64::from(height) {
        return Err(EnvironmentError::Size {
            width,
            height,
            pixels: pixels.len(),
        });
    }
    let (w, h) = (f64::from(width), f64::from(height));
    let step = (2.0 * std::f64::consts::PI / w) * (std::f64::consts::PI / h);
    let mut sum = [[0.0f64; 3]; SH_COEFFICIENTS];
    for (y, row) in pixels.chunks_exact(width as usize).enumerate() {
        let theta = std::f64::consts::PI * (y as f64 + 0.5) / h;
        let (sin_t, cos_t) = theta.sin_cos();
        let weight = step * sin_t;
        for (x, p) in row.iter().enumerate() {
            if !p.iter().all(|v| v.is_finite() && *v >= 0.0) {
                return Err(EnvironmentError::BadPixel {
                    x: x as u32,
                    y: y as u32,
                    value: *p,
                });
            }
            let phi = 2.0 * std::f64::consts::PI * ((x as f64 + 0.5) / w - 0.5);
            let (sin_p, cos_p) = phi.sin_cos();
            let basis = sh_basis([sin_t * cos_p, cos_t, sin_t * sin_p]);
            for (s, b) in sum.iter_mut().zip(basis) {
                for c in 0..3 {
                    s[c] += f64::from(p[c]) * b * weight;
                }
            }
        }
    }
    Ok(sum.map(|s| s.map(|v| v as f32)))
}

fn check_size(width: u32, height: u32) -> Result<(), EnvironmentError> {
    if width > MAX_SIDE || height > MAX_SIDE || u64::from(width) * u64::from(height) > MAX_PIXELS {
        return Err(EnvironmentError::TooLarge { width, height });
    }
    Ok(())
}

/// An environment image projected to a sky.
#[derive(Debug, Clone, PartialEq)]
pub struct Environment {
    /// The sky's radiance coefficients, as a sky light's `sh` takes them.
    pub sh: [[f32; 3]; SH_COEFFICIENTS],
    pub width: u32,
    pub height: u32,
}

/// The SH coefficients of an equirectangular image file's bytes (Radiance `.hdr` or OpenEXR,
/// told apart by their first bytes). The size is checked from the header before the pixels are
/// decoded, so a hostile header cannot make it allocate more than [`MAX_PIXELS`] allow.
pub fn sh_from_image(bytes: &[u8]) -> Result<Environment, EnvironmentError> {
    use image::ImageDecoder;
    let format = image::guess_format(bytes).map_err(|e| EnvironmentError::Format(e.to_string()))?;
    let cursor = std::io::Cursor::new(bytes);
    let decoded = match format {
        image::ImageFormat::Hdr => {
            let d = image::codecs::hdr::HdrDecoder::new(cursor)
                .map_err(|e| EnvironmentError::Format(e.to_string()))?;
            let (w, h) = d.dimensions();
            check_size(w, h)?;
            image::DynamicImage::from_decoder(d)
        }
        image::ImageFormat::OpenExr => {
            let d = image::codecs::openexr::OpenExrDecoder::new(cursor)
                .map_err(|e| EnvironmentError::Format(e.to_string()))?;
            let (w, h) = d.dimensions();
            check_size(w, h)?;
            image::DynamicImage::from_decoder(d)
        }
        other => {
            return Err(EnvironmentError::Format(format!(
                "{other:?} holds no high dynamic range"
            )));
        }
    }
    .map_err(|e| EnvironmentError::Format(e.to_string()))?;
    let rgb = decoded.to_rgb32f();
    let (width, height) = rgb.dimensions();
    let pixels: Vec<[f32; 3]> = rgb.pixels().map(|p| p.0).collect();
    Ok(Environment {
        sh: project_equirect(width, height, &pixels)?,
        width,
        height,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use bounce_types::sh::{sh_radiance, uniform_sh};

    /// A `w × h` map of radiance `f(direction)`, the module doc's mapping.
    fn map(w: u32, h: u32, f: impl Fn([f64; 3]) -> [f32; 3]) -> Vec<[f32; 3]> {
        let mut out = Vec::with_capacity((w * h) as usize);
        for y in 0..h {
            let theta = std::f64::consts::PI * (f64::from(y) + 0.5) / f64::from(h);
            for x in 0..w {
                let phi = 2.0 * std::f64::consts::PI * ((f64::from(x) + 0.5) / f64::from(w) - 0.5);
                out.push(f([
                    theta.sin() * phi.cos(),
                    theta.cos(),
                    theta.sin() * phi.sin(),
                ]));
            }
        }
        out
    }

    fn close(a: &[[f32; 3]; 9], b: &[[f32; 3]; 9], tol: f32) {
        for (x, y) in a.iter().flatten().zip(b.iter().flatten()) {
            assert!((x - y).abs() <= tol, "{a:?}\n{b:?}");
        }
    }

    #[test]
    fn a_uniform_map_is_a_uniform_sky() {
        let c = [0.5, 1.0, 2.0];
        let sh = project_equirect(256, 128, &map(256, 128, |_| c)).unwrap();
        // The midpoint rule's error over the poles' rows: a few parts in 10⁵ of L00.
        close(&sh, &uniform_sh(c), 5e-4);
    }

    /// Any order-2 radiance drawn into a map comes back as its coefficients: the projection is
    /// the basis' own inner product, and the basis is orthonormal.
    #[test]
    fn an_order_2_map_gives_back_its_coefficients() {
        let mut want = [[0.0f32; 3]; 9];
        for (k, w) in want.iter_mut().enumerate() {
            *w = [
                1.0 + k as f32 * 0.1,
                0.3 * k as f32 - 1.0,
                0.05 * (k * k) as f32,
            ];
        }
        // Keep it a radiance (non-negative) by lifting the constant term.
        want[0] = [12.0, 12.0, 12.0];
        let pixels = map(512, 256, |d| sh_radiance(&want, d).map(|v| v as f32));
        assert!(pixels.iter().flatten().all(|v| *v >= 0.0));
        let sh = project_equirect(512, 256, &pixels).unwrap();
        close(&sh, &want, 2e-3);
    }

    /// The map's top row is the zenith (+Y) and its middle column looks along +X.
    #[test]
    fn the_top_is_up_and_the_middle_looks_along_x() {
        let up = project_equirect(64, 32, &map(64, 32, |d| [d[1].max(0.0) as f32; 3])).unwrap();
        // Y1−1 is y: only it of the order-1 terms.
        assert!(
            up[1][0] > 0.5 && up[2][0].abs() < 1e-3 && up[3][0].abs() < 1e-3,
            "{up:?}"
        );
        let mut pixels = vec![[0.0f32; 3]; 64 * 32];
        // A bright spot in the middle of the middle row: +X.
        pixels[16 * 64 + 32] = [100.0; 3];
        let x = project_equirect(64, 32, &pixels).unwrap();
        assert!(x[3][0] > 0.0 && x[3][0] > 10.0 * x[2][0].abs() && x[3][0] > 10.0 * x[1][0].abs());
    }

    #[test]
    fn bad_images_are_refused() {
        assert!(matches!(
            project_equirect(0, 4, &[]),
            Err(EnvironmentError::Empty { .. })
        ));
        assert!(matches!(
            project_equirect(4, 2, &[[0.0; 3]; 7]),
            Err(EnvironmentError::Size { .. })
        ));
        let mut p = vec![[1.0f32; 3]; 8];
        p[5] = [f32::NAN, 0.0, 0.0];
        assert!(matches!(
            project_equirect(4, 2, &p),
            Err(EnvironmentError::BadPixel { x: 1, y: 1, .. })
        ));
        p[5] = [-1.0, 0.0, 0.0];
        assert!(project_equirect(4, 2, &p).is_err());
        assert!(matches!(
            project_equirect(MAX_SIDE + 1, 1, &[]),
            Err(EnvironmentError::TooLarge { .. })
        ));
        assert!(matches!(
            sh_from_image(b"not an image at all"),
            Err(EnvironmentError::Format(_))
        ));
        // A PNG is an image, but not a radiance one.
        let mut png = Vec::new();
        image::RgbImage::new(2, 1)
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        let e = sh_from_image(&png).unwrap_err();
        assert!(e.to_string().contains("high dynamic range"), "{e}");
    }

    /// A Radiance `.hdr` file through the image crate's own encoder reads back as its pixels
    /// project (RGBE keeps 8 bits of mantissa: within a percent).
    #[test]
    fn an_hdr_file_projects_as_its_pixels() {
        let (w, h) = (64u32, 32u32);
        let pixels = map(w, h, |d| [(1.0 + d[1]) as f32, 0.5, (2.0 - d[0]) as f32]);
        let mut bytes = Vec::new();
        let rgb: Vec<image::Rgb<f32>> = pixels.iter().map(|p| image::Rgb(*p)).collect();
        image::codecs::hdr::HdrEncoder::new(&mut bytes)
            .encode(&rgb, w as usize, h as usize)
            .unwrap();
        let from_file = sh_from_image(&bytes).unwrap();
        assert_eq!((from_file.width, from_file.height), (w, h));
        let direct = project_equirect(w, h, &pixels).unwrap();
        close(&from_file.sh, &direct, 0.02 * 4.0);
        // A header that claims more than the limit is refused before decoding.
        let huge = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 100000 +X 100000\n";
        assert!(matches!(
            sh_from_image(huge),
            Err(EnvironmentError::TooLarge { .. }) | Err(EnvironmentError::Format(_))
        ));
    }
}
