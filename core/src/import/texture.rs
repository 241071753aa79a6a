//! Base-colour and emissive textures reduced to one linear colour per triangle.
//!
//! Radiosity needs one albedo per triangle, so a texture is averaged over the triangle's UV
//! footprint: sampled (bilinear, with the sampler's wrap modes) at the centroids of a regular
//! subdivision of the triangle, so the samples are stratified and equally weighted. Texels are
//! sRGB-encoded and converted to linear before any filtering or averaging.

use std::io::Cursor;
use std::sync::OnceLock;

use glam::{Affine2, Mat2, Vec2, Vec3};
use gltf::texture::{MagFilter, WrappingMode};

/// Subdivision cap: at most `MAX_SPLIT²` = 64 samples per triangle.
const MAX_SPLIT: usize = 8;

/// A decoded image, still sRGB-encoded, 8 bits per channel. Alpha is dropped unless asked for:
/// it does not change a diffuse albedo, but a viewer drawing the image needs it.
pub(crate) struct Image {
    width: usize,
    height: usize,
    /// 3 (RGB) or 4 (RGBA) bytes per texel, rows top to bottom.
    channels: usize,
    pixels: Vec<u8>,
    mean: Vec3,
}

impl Image {
    /// Decodes PNG or JPEG, recognised by content first (files are often mislabelled), then by
    /// the declared MIME type. `keep_alpha` keeps RGBA texels so the pixels can be handed on
    /// as they are instead of decoding the image a second time.
    pub(crate) fn decode(
        bytes: &[u8],
        mime: Option<&str>,
        keep_alpha: bool,
    ) -> Result<Self, String> {
        let format = match image::guess_format(bytes) {
            Ok(format) => format,
            Err(_) => match mime {
                Some("image/png") => image::ImageFormat::Png,
                Some("image/jpeg") => image::ImageFormat::Jpeg,
                Some(other) => return Err(format!("unsupported image type '{other}'")),
                None => return Err("unrecognised image format".into()),
            },
        };
        // The default limits cap the decoder's allocation, so a hostile header cannot make us
        // reserve gigabytes.
        let reader = image::ImageReader::with_format(Cursor::new(bytes), format);
        let decoded = reader.decode().map_err(|e| e.to_string())?;
        let (width, height) = (decoded.width() as usize, decoded.height() as usize);
        if width == 0 || height == 0 {
            return Err("image has no pixels".into());
        }
        let (channels, pixels) = if keep_alpha {
            (4, decoded.into_rgba8().into_raw())
        } else {
            (3, decoded.into_rgb8().into_raw())
        };
        let lut = srgb_to_linear_table();
        let mut sum = [0f64; 3];
        for px in pixels.chunks_exact(channels) {
            for (s, &c) in sum.iter_mut().zip(px) {
                *s += f64::from(lut[usize::from(c)]);
            }
        }
        let n = (width * height) as f64;
        let mean = Vec3::new(
            (sum[0] / n) as f32,
            (sum[1] / n) as f32,
            (sum[2] / n) as f32,
        );
        Ok(Image {
            width,
            height,
            channels,
            pixels,
            mean,
        })
    }

    pub(crate) fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// The RGBA texels, if the image was decoded keeping alpha.
    pub(crate) fn into_rgba(self) -> Option<Vec<u8>> {
        (self.channels == 4).then_some(self.pixels)
    }

    /// Linear mean of the whole image: the best guess when a primitive has no texture coordinates.
    pub(crate) fn mean(&self) -> Vec3 {
        self.mean
    }

    fn texel(&self, x: usize, y: usize) -> Vec3 {
        let lut = srgb_to_linear_table();
        let at = (y * self.width + x) * self.channels;
        match self.pixels.get(at..at + 3) {
            Some(&[r, g, b]) => Vec3::new(
                lut[usize::from(r)],
                lut[usize::from(g)],
                lut[usize::from(b)],
            ),
            _ => Vec3::ZERO,
        }
    }
}

/// How a texture is looked up: wrap modes, filter, and the `KHR_texture_transform` UV transform.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Lookup {
    pub wrap_s: WrappingMode,
    pub wrap_t: WrappingMode,
    pub nearest: bool,
    pub transform: Affine2,
}

impl Lookup {
    pub(crate) fn new(sampler: &gltf::texture::Sampler<'_>, transform: Affine2) -> Self {
        Lookup {
            wrap_s: sampler.wrap_s(),
            wrap_t: sampler.wrap_t(),
            nearest: sampler.mag_filter() == Some(MagFilter::Nearest),
            transform,
        }
    }

    /// Mean linear colour of `image` over the triangle with texture coordinates `uv`.
    pub(crate) fn footprint_average(&self, image: &Image, uv: [Vec2; 3]) -> Vec3 {
        let [a, b, c] = uv.map(|p| self.transform.transform_point2(p));
        let (e1, e2) = (b - a, c - a);
        let texels = 0.5 * e1.perp_dot(e2).abs() * (image.width * image.height) as f32;
        // About two samples per covered texel, up to the cap: one sample per texel lands on
        // texel boundaries too often to average a sharp edge. `k` subdivisions per edge give k²
        // samples.
        let k = if texels.is_finite() {
            ((2.0 * texels).sqrt().ceil() as usize).clamp(1, MAX_SPLIT)
        } else {
            MAX_SPLIT
        };
        let kf = k as f32;
        let mut sum = Vec3::ZERO;
        for i in 0..k {
            for j in 0..k - i {
                // Upward sub-triangle (i, j), then the downward one beside it if there is one.
                let (fi, fj) = (i as f32, j as f32);
                sum += self.sample(
                    image,
                    a + e1 * ((fi + 1.0 / 3.0) / kf) + e2 * ((fj + 1.0 / 3.0) / kf),
                );
                if i + j + 1 < k {
                    sum += self.sample(
                        image,
                        a + e1 * ((fi + 2.0 / 3.0) / kf) + e2 * ((fj + 2.0 / 3.0) / kf),
                    );
                }
            }
        }
        sum / (k * k) as f32
    }

    /// Bilinear (or nearest) lookup of the linear colour at `uv`; glTF's UV origin is the image's
    /// top-left corner, as in the decoded pixel rows.
    fn sample(&self, image: &Image, uv: Vec2) -> Vec3 {
        let uv = if uv.is_finite() { uv } else { Vec2::ZERO };
        let (w, h) = (image.width as i64, image.height as i64);
        let x = f64::from(uv.x) * w as f64 - 0.5;
        let y = f64::from(uv.y) * h as f64 - 0.5;
        if self.nearest {
            let xi = wrap(x.round() as i64, w, self.wrap_s);
            let yi = wrap(y.round() as i64, h, self.wrap_t);
            return image.texel(xi, yi);
        }
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let (xa, xb) = (
            wrap(x0, w, self.wrap_s),
            wrap(x0.saturating_add(1), w, self.wrap_s),
        );
        let (ya, yb) = (
            wrap(y0, h, self.wrap_t),
            wrap(y0.saturating_add(1), h, self.wrap_t),
        );
        let top = image.texel(xa, ya).lerp(image.texel(xb, ya), fx);
        let bottom = image.texel(xa, yb).lerp(image.texel(xb, yb), fx);
        top.lerp(bottom, fy)
    }
}

/// The `KHR_texture_transform` matrix: `translation × rotation × scale`, rotation as in the
/// extension's GLSL (column-major `mat3(cos, sin, 0, -sin, cos, 0, 0, 0, 1)`).
pub(crate) fn uv_transform(offset: Vec2, rotation: f32, scale: Vec2) -> Affine2 {
    let (s, c) = rotation.sin_cos();
    let r = Mat2::from_cols(Vec2::new(c, s), Vec2::new(-s, c));
    Affine2::from_mat2_translation(r * Mat2::from_diagonal(scale), offset)
}

fn wrap(i: i64, n: i64, mode: WrappingMode) -> usize {
    let i = match mode {
        WrappingMode::ClampToEdge => i.clamp(0, n - 1),
        WrappingMode::Repeat => i.rem_euclid(n),
        WrappingMode::MirroredRepeat => {
            let m = i.rem_euclid(2 * n);
            if m < n { m } else { 2 * n - 1 - m }
        }
    };
    i as usize
}

fn srgb_to_linear_table() -> &'static [f32; 256] {
    static TABLE: OnceLock<[f32; 256]> = OnceLock::new();
    TABLE.get_or_init(|| {
        std::array::from_fn(|i| {
            let c = i as f32 / 255.0;
            if c <= 0.04045 {
                c / 12.92
            } else {
                ((c + 0.055) / 1.055).powf(2.4)
            }
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn checker() -> Image {
        // 2×1: black then white (sRGB 255 = linear 1).
        Image {
            width: 2,
            height: 1,
            channels: 3,
            pixels: vec![0, 0, 0, 255, 255, 255],
            mean: Vec3::splat(0.5),
        }
    }

    fn lookup(mode: WrappingMode) -> Lookup {
        Lookup {
            wrap_s: mode,
            wrap_t: mode,
            nearest: false,
            transform: Affine2::IDENTITY,
        }
    }

    #[test]
    fn rgba_images_sample_like_rgb_ones_and_hand_their_texels_on() {
        let rgba = Image {
            width: 2,
            height: 1,
            channels: 4,
            pixels: vec![0, 0, 0, 7, 255, 255, 255, 9],
            mean: Vec3::splat(0.5),
        };
        let tri = [
            Vec2::new(0.8, 0.4),
            Vec2::new(0.85, 0.4),
            Vec2::new(0.8, 0.45),
        ];
        let l = lookup(WrappingMode::ClampToEdge);
        assert_eq!(
            l.footprint_average(&rgba, tri),
            l.footprint_average(&checker(), tri)
        );
        assert_eq!(checker().into_rgba(), None);
        assert_eq!(rgba.into_rgba(), Some(vec![0, 0, 0, 7, 255, 255, 255, 9]));
    }

    #[test]
    fn wrap_modes() {
        assert_eq!(wrap(-1, 4, WrappingMode::Repeat), 3);
        assert_eq!(wrap(-1, 4, WrappingMode::ClampToEdge), 0);
        assert_eq!(wrap(-1, 4, WrappingMode::MirroredRepeat), 0);
        assert_eq!(wrap(5, 4, WrappingMode::MirroredRepeat), 2);
        assert_eq!(wrap(i64::MAX, 4, WrappingMode::Repeat), 3);
    }

    #[test]
    fn srgb_mid_grey_is_about_0_214_linear() {
        assert!((srgb_to_linear_table()[128] - 0.2158).abs() < 1e-3);
    }

    #[test]
    fn a_footprint_symmetric_over_repeated_tiles_averages_to_the_image_mean() {
        let tri = [
            Vec2::new(0.0, 0.0),
            Vec2::new(8.0, 0.0),
            Vec2::new(4.0, 4.0),
        ];
        let avg = lookup(WrappingMode::Repeat).footprint_average(&checker(), tri);
        assert!((avg.x - 0.5).abs() < 0.05, "{avg}");
    }

    #[test]
    fn a_triangle_inside_one_texel_takes_its_colour() {
        let tri = [
            Vec2::new(0.8, 0.4),
            Vec2::new(0.85, 0.4),
            Vec2::new(0.8, 0.45),
        ];
        let avg = lookup(WrappingMode::ClampToEdge).footprint_average(&checker(), tri);
        assert!((avg.x - 1.0).abs() < 1e-4, "{avg}");
    }

    #[test]
    fn transform_offsets_then_rotates_then_scales() {
        let t = uv_transform(
            Vec2::new(1.0, 0.0),
            std::f32::consts::FRAC_PI_2,
            Vec2::splat(2.0),
        );
        let p = t.transform_point2(Vec2::new(1.0, 0.0));
        assert!((p - Vec2::new(1.0, 2.0)).length() < 1e-5, "{p}");
    }
}
