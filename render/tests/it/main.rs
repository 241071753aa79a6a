//! The renderer end to end on lavapipe (or any adapter): the Cornell box baked here, relit
//! in-process, drawn with and without indirect light, measured in pixels; the shader's volume
//! sampling against `Volume::sample`; the shared structs against the WGSL; a golden image.
//!
//! GPU tests never skip silently: without an adapter they fail, unless `BOUNCE_ALLOW_NO_GPU=1`.

mod probe_sphere;

use std::path::Path;
use std::sync::OnceLock;

use bounce_client::{Face, Volume};
use bounce_core::bake::{BakeOptions, NoProgress, bake_file};
use bounce_core::format::Baked;
use bounce_core::import::{ImportOptions, import_path_with};
use bounce_core::light::{Light, LightSet};
use bounce_core::scene::{Scene, Shading, ShadingTexture, TriangleShading};
use bounce_core::voxel::Resolution;
use bounce_engine::gpu::GpuContext;
use bounce_engine::{Engine, EngineChoice};
use bounce_render::{
    Camera, Globals, Image, Object, OverlayParams, RenderOptions, Renderer, volume_from_baked,
};
use glam::{UVec3, Vec3};

use bounce_testkit::cornell_gltf as gltf;
use bounce_testkit::fixtures::gpu_context as context;

struct Cornell {
    scene: Scene,
    baked: Baked,
}

fn cornell() -> &'static Cornell {
    static BOX: OnceLock<Cornell> = OnceLock::new();
    BOX.get_or_init(|| {
        let options = BakeOptions {
            resolution: Resolution::TargetPatches(500),
            rays: 512,
            // The golden image was drawn from this voxel-face bake.
            geometry: bounce_core::voxel::Geometry::VoxelFaces,
            ..BakeOptions::default()
        };
        Cornell {
            scene: import_path_with(&gltf(), &ImportOptions { shading: true })
                .expect("importing the Cornell box"),
            baked: bake_file(&gltf(), &options, &NoProgress).expect("baking the Cornell box"),
        }
    })
}

/// A spot under the ceiling pointing down: the ceiling gets no direct light at all.
fn spot() -> LightSet {
    LightSet {
        lights: vec![Light::Spot {
            position: [0.0, 1.9, 0.0],
            direction: [0.0, -1.0, 0.0],
            color: [1.0, 1.0, 1.0],
            intensity: 15.0,
            range: None,
            inner_cone_angle: 0.8,
            outer_cone_angle: 1.0,
            name: None,
        }],
    }
}

fn volume(lights: &LightSet) -> Volume {
    let b = cornell();
    let engine = Engine::new(EngineChoice::Cpu).unwrap();
    let scene = engine.load(&b.baked).unwrap();
    let lit = engine
        .relight(&scene, std::slice::from_ref(lights))
        .unwrap();
    volume_from_baked("cornell-box", &b.baked.layout, &lit[0].indirect).unwrap()
}

fn camera() -> Camera {
    Camera::framing(cornell().scene.bounds().unwrap())
}

fn render(ctx: &GpuContext, width: u32, height: u32, indirect: bool) -> Image {
    render_with(ctx, &spot(), width, height, indirect)
}

fn render_with(
    ctx: &GpuContext,
    lights: &LightSet,
    width: u32,
    height: u32,
    indirect: bool,
) -> Image {
    Renderer::new(ctx)
        .unwrap()
        .render(
            &cornell().scene,
            &camera(),
            lights,
            &volume(lights),
            &RenderOptions {
                width,
                height,
                exposure: 1.0,
                indirect,
                direct: true,
            },
        )
        .unwrap()
}

/// Where a world point lands in the image (the renderer's camera convention: right-handed,
/// Y up, rows top to bottom).
fn project(image: &Image, p: Vec3) -> (u32, u32) {
    let aspect = image.width as f32 / image.height as f32;
    let m = camera()
        .view_proj(aspect, cornell().scene.bounds().unwrap())
        .unwrap();
    let ndc = m.project_point3(p);
    let x = (ndc.x * 0.5 + 0.5) * image.width as f32;
    let y = (0.5 - ndc.y * 0.5) * image.height as f32;
    (x as u32, y as u32)
}

/// Mean linear RGB of a (2r+1)² window around a world point.
fn mean_rgb(image: &Image, p: Vec3, r: i64) -> Vec3 {
    let (cx, cy) = project(image, p);
    let mut sum = Vec3::ZERO;
    let mut n = 0.0;
    for y in cy as i64 - r..=cy as i64 + r {
        for x in cx as i64 - r..=cx as i64 + r {
            assert!(x >= 0 && y >= 0 && x < image.width as i64 && y < image.height as i64);
            let i = ((y as u32 * image.width + x as u32) * 4) as usize;
            let px = &image.pixels[i..i + 3];
            sum += Vec3::new(srgb(px[0]), srgb(px[1]), srgb(px[2]));
            n += 1.0;
        }
    }
    sum / n
}

fn srgb(v: u8) -> f32 {
    let c = f32::from(v) / 255.0;
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

fn luminance(c: Vec3) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

const CEILING: Vec3 = Vec3::new(0.4, 1.98, -0.4);
const FLOOR_BY_RED: Vec3 = Vec3::new(-0.85, 0.01, 0.8);
const FLOOR_BY_GREEN: Vec3 = Vec3::new(0.85, 0.01, 0.5);

#[test]
fn indirect_light_brightens_the_unlit_ceiling() {
    let Some(ctx) = context() else { return };
    let on = render(ctx, 320, 240, true);
    let off = render(ctx, 320, 240, false);
    let lit = luminance(mean_rgb(&on, CEILING, 4));
    let dark = luminance(mean_rgb(&off, CEILING, 4));
    eprintln!("ceiling luminance: indirect on {lit:.4}, off {dark:.4}");
    // The spot points down: without indirect light the ceiling is black.
    assert!(dark < 0.002, "{dark}");
    assert!(lit > dark + 0.02, "on {lit}, off {dark}");
}

#[test]
fn the_floor_by_the_red_wall_is_redder() {
    let Some(ctx) = context() else { return };
    let on = render(ctx, 320, 240, true);
    let off = render(ctx, 320, 240, false);
    let ratio = |c: Vec3| c.x / c.y;
    let red_on = ratio(mean_rgb(&on, FLOOR_BY_RED, 3));
    let red_off = ratio(mean_rgb(&off, FLOOR_BY_RED, 3));
    let green_on = ratio(mean_rgb(&on, FLOOR_BY_GREEN, 3));
    eprintln!(
        "r/g by the red wall: on {red_on:.3}, off {red_off:.3}; by the green wall {green_on:.3}"
    );
    assert!(red_on > red_off * 1.05, "on {red_on}, off {red_off}");
    assert!(
        red_on > green_on * 1.1,
        "red side {red_on}, green side {green_on}"
    );
}

/// Linear images are radiance itself: direct + indirect is the sum of the two drawn apart
/// (indirect only has no direct light and no emission), and the tonemap of the sum is the PNG.
#[test]
fn linear_images_add_up_and_tonemap_to_the_png() {
    let Some(ctx) = context() else { return };
    let renderer = Renderer::new(ctx).unwrap();
    let lights = spot();
    let v = volume(&lights);
    let linear = |direct, indirect| {
        let options = RenderOptions {
            width: 80,
            height: 60,
            exposure: 3.0,
            indirect,
            direct,
        };
        renderer
            .render_linear(&cornell().scene, &camera(), &lights, &v, &options)
            .unwrap()
    };
    let both = linear(true, true);
    let direct = linear(true, false);
    let indirect = linear(false, true);
    assert_eq!(both.pixels.len(), 80 * 60);
    let mut lit = 0;
    for ((b, d), i) in both.pixels.iter().zip(&direct.pixels).zip(&indirect.pixels) {
        for c in 0..3 {
            assert!(
                (b[c] - (d[c] + i[c])).abs() <= 1e-5 * b[c].max(1.0),
                "{b:?} {d:?} {i:?}"
            );
        }
        if i.iter().all(|&x| x > 0.0) && d.iter().all(|&x| x == 0.0) {
            lit += 1;
        }
    }
    // The ceiling: no direct light from the spot below it, indirect light only.
    assert!(lit > 100, "{lit}");
    let png = renderer
        .render(
            &cornell().scene,
            &camera(),
            &lights,
            &v,
            &RenderOptions {
                width: 80,
                height: 60,
                exposure: 3.0,
                indirect: true,
                direct: true,
            },
        )
        .unwrap();
    for (k, b) in both.pixels.iter().enumerate() {
        for (c, radiance) in b.iter().enumerate() {
            let x = radiance * 3.0;
            let want = x / (1.0 + x);
            let got = srgb(png.pixels[4 * k + c]);
            assert!(
                (got - want).abs() <= 0.01 * want + 2e-3,
                "pixel {k}: {got} against {want}"
            );
        }
    }
}

/// The trilinear coverage around a point (separators aside), to keep test points away from the
/// threshold where the two may legitimately disagree.
fn coverage(v: &Volume, face: Face, p: Vec3) -> f32 {
    let u = (p - v.origin()) / v.voxel_size() - 0.5;
    let max = v.dims().as_ivec3() - 1;
    let lo = u.floor();
    let f = u - lo;
    let mut acc = 0.0;
    for corner in 0..8 {
        let step = Vec3::new(
            (corner & 1) as f32,
            ((corner >> 1) & 1) as f32,
            ((corner >> 2) & 1) as f32,
        );
        let w = Vec3::select(step.cmpeq(Vec3::ONE), f, Vec3::ONE - f).element_product();
        let t = (lo + step)
            .as_ivec3()
            .clamp(glam::IVec3::ZERO, max)
            .as_uvec3();
        acc += w * v.texel(face, t).unwrap()[3].to_f32();
    }
    acc
}

#[test]
fn shader_volume_sampling_matches_the_cpu_sampler() {
    let Some(ctx) = context() else { return };
    let v = volume(&spot());
    let size = v.voxel_size() * v.dims().as_vec3();
    let mut seed = 0x1234_5678u32;
    let mut rand = move || {
        seed ^= seed << 13;
        seed ^= seed >> 17;
        seed ^= seed << 5;
        seed as f32 / u32::MAX as f32
    };
    let mut points = Vec::new();
    while points.len() < 400 {
        let mut n = Vec3::new(rand() - 0.5, rand() - 0.5, rand() - 0.5);
        // Half anywhere in (and a little around) the grid with any normal, half near patches
        // with a normal leaning towards the patch's face (the grid the sampler reads).
        let p = if points.len() % 2 == 0 {
            v.origin() + size * Vec3::new(rand(), rand(), rand()) * 1.1 - size * 0.05
        } else {
            let b = &cornell().baked.layout;
            let patch = &b.patches[(rand() * (b.patches.len() - 1) as f32) as usize];
            n += patch.face.normal();
            let centre =
                v.origin() + (UVec3::from_array(patch.voxel).as_vec3() + 0.5) * v.voxel_size();
            centre + (Vec3::new(rand(), rand(), rand()) - 0.5) * v.voxel_size()
        };
        if n.length() < 0.1 {
            continue;
        }
        let near_threshold = (0..3).any(|a| {
            let face = Face::from_axis_sign(a, n[a] >= 0.0);
            let c = coverage(&v, face, p);
            c > 0.0 && c < 0.05
        });
        if !near_threshold {
            points.push((p, n.normalize()));
        }
    }
    let gpu = Renderer::new(ctx)
        .unwrap()
        .probe_volume(&v, &points)
        .unwrap();
    let scale = (0..points.len())
        .map(|i| {
            v.sample(points[i].0, points[i].1)
                .into_iter()
                .fold(0.0f32, f32::max)
        })
        .fold(0.0f32, f32::max);
    assert!(scale > 0.0);
    let mut nonzero = 0;
    for (i, &(p, n)) in points.iter().enumerate() {
        let cpu = v.sample(p, n);
        if cpu.iter().any(|&c| c > 0.0) {
            nonzero += 1;
        }
        for k in 0..3 {
            // The shader weighs the f16 texels itself in f32, as the CPU does; the margin is for
            // a point within rounding of a voxel boundary, where the own voxel may differ.
            let tol = 1e-2 * cpu[k].abs() + 4e-3 * scale;
            assert!(
                (gpu[i][k] - cpu[k]).abs() <= tol,
                "point {i} {p} normal {n}: gpu {:?}, cpu {cpu:?}",
                gpu[i]
            );
        }
    }
    eprintln!(
        "{} points, {nonzero} with light, scale {scale}",
        points.len()
    );
    assert!(nonzero >= 100, "{nonzero}");
}

fn wgsl_struct(module: &naga::Module, name: &str) -> (Vec<(String, u32)>, u32) {
    module
        .types
        .iter()
        .find_map(|(_, ty)| match (&ty.name, &ty.inner) {
            (Some(n), naga::TypeInner::Struct { members, span }) if n == name => Some((
                members
                    .iter()
                    .map(|m| (m.name.clone().unwrap_or_default(), m.offset))
                    .collect(),
                *span,
            )),
            _ => None,
        })
        .unwrap_or_else(|| panic!("no struct {name}"))
}

macro_rules! offsets {
    ($t:ty; $($f:ident),*) => {
        vec![$((stringify!($f).to_string(), std::mem::offset_of!($t, $f) as u32)),*]
    };
}

#[test]
fn shared_structs_match_the_wgsl() {
    // The whole shader as the renderer compiles it, the engine's light module included; that
    // module's `GpuLight` is checked once, in bounce-engine's layout tests.
    let shader = bounce_render::shade_source();
    let module = naga::front::wgsl::parse_str(&shader)
        .unwrap_or_else(|e| panic!("{}", e.emit_to_string(&shader)));
    let (members, span) = wgsl_struct(&module, "Globals");
    assert_eq!(span as usize, std::mem::size_of::<Globals>());
    assert_eq!(
        members,
        offsets!(Globals; view_proj, eye, exposure, volume_origin, voxel_size, volume_dims,
            light_count, indirect, normal_offset, flags, pad1)
    );

    let (members, span) = wgsl_struct(&module, "Object");
    assert_eq!(span as usize, std::mem::size_of::<Object>());
    assert_eq!(members, offsets!(Object; centre, radius, albedo, pad, cube));

    let overlay = naga::front::wgsl::parse_str(bounce_render::OVERLAY_SHADER)
        .unwrap_or_else(|e| panic!("{}", e.emit_to_string(bounce_render::OVERLAY_SHADER)));
    let (members, span) = wgsl_struct(&overlay, "OverlayParams");
    assert_eq!(span as usize, std::mem::size_of::<OverlayParams>());
    assert_eq!(
        members,
        offsets!(OverlayParams; origin, size, target_size, pad)
    );
}

/// The Cornell box under the spot at 160×120 against `tests/golden/cornell-spot.png`, rendered
/// on lavapipe; `BOUNCE_BLESS=1` rewrites it. Other adapters round differently: a pixel may be
/// off by a few levels, and a small share of pixels (edges, shadow borders) by more.
#[test]
fn golden_image() {
    let Some(ctx) = context() else { return };
    let image = render(ctx, 160, 120, true);
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden/cornell-spot.png");
    if std::env::var("BOUNCE_BLESS").as_deref() == Ok("1") {
        image::save_buffer(
            &path,
            &image.pixels,
            image.width,
            image.height,
            image::ColorType::Rgba8,
        )
        .unwrap();
        eprintln!("blessed {}", path.display());
        return;
    }
    let golden = image::open(&path)
        .unwrap_or_else(|e| panic!("{}: {e} (BOUNCE_BLESS=1 writes it)", path.display()))
        .to_rgba8();
    assert_eq!(golden.dimensions(), (image.width, image.height));
    const LEVELS: i16 = 6;
    let differing = golden
        .as_raw()
        .chunks(4)
        .zip(image.pixels.chunks(4))
        .filter(|(a, b)| {
            a.iter()
                .zip(b.iter())
                .any(|(&x, &y)| (i16::from(x) - i16::from(y)).abs() > LEVELS)
        })
        .count();
    let share = differing as f64 / f64::from(image.width * image.height);
    eprintln!(
        "{differing} pixels differ by more than {LEVELS} levels ({:.3}%)",
        share * 100.0
    );
    assert!(
        share <= 0.01,
        "{differing} pixels differ ({:.2}%)",
        share * 100.0
    );
}

/// Every kind of light casts shadows: lit from the open front along −Z, the short box shadows
/// the back wall behind it (a point just above the box's silhouette as the camera sees it, so
/// visible), while higher up the wall is lit.
#[test]
fn every_light_kind_casts_shadows() {
    let Some(ctx) = context() else { return };
    const SHADOWED: Vec3 = Vec3::new(0.4, 0.55, -1.03);
    const LIT: Vec3 = Vec3::new(0.4, 1.5, -1.03);
    let from = [0.375, 0.3, 3.0];
    let kinds = [
        Light::Directional {
            direction: [0.0, 0.0, -1.0],
            color: [1.0; 3],
            intensity: 2.0,
            name: None,
        },
        Light::Point {
            position: from,
            color: [1.0; 3],
            intensity: 30.0,
            range: None,
            name: None,
        },
        Light::Spot {
            position: from,
            direction: [0.0, 0.0, -1.0],
            color: [1.0; 3],
            intensity: 30.0,
            range: None,
            inner_cone_angle: 0.4,
            outer_cone_angle: 0.6,
            name: None,
        },
    ];
    for light in kinds {
        let lights = LightSet {
            lights: vec![light.clone()],
        };
        let image = render_with(ctx, &lights, 320, 240, false);
        let dark = luminance(mean_rgb(&image, SHADOWED, 1));
        let lit = luminance(mean_rgb(&image, LIT, 1));
        eprintln!("{light:?}: shadowed {dark:.4}, lit {lit:.4}");
        assert!(lit > 0.05, "{light:?}: {lit}");
        assert!(dark < 0.1 * lit, "{light:?}: shadowed {dark}, lit {lit}");
    }
}

#[test]
fn too_many_shadow_maps_or_a_bad_size_are_errors() {
    let Some(ctx) = context() else { return };
    let point = Light::Point {
        position: [0.0, 1.0, 0.0],
        color: [1.0; 3],
        intensity: 1.0,
        range: None,
        name: None,
    };
    let lights = LightSet {
        lights: vec![point; bounce_render::MAX_SHADOW_VIEWS / 6 + 1],
    };
    let renderer = Renderer::new(ctx).unwrap();
    let v = volume(&spot());
    let options = |width, height| RenderOptions {
        width,
        height,
        exposure: 1.0,
        indirect: true,
        direct: true,
    };
    let err = renderer
        .render(&cornell().scene, &camera(), &lights, &v, &options(8, 8))
        .unwrap_err();
    assert!(err.to_string().contains("shadow maps"), "{err}");
    for (w, h) in [(0, 8), (8, bounce_render::MAX_SIDE + 1)] {
        let err = renderer
            .render(&cornell().scene, &camera(), &spot(), &v, &options(w, h))
            .unwrap_err();
        assert!(err.to_string().contains("image size"), "{err}");
    }
}

/// A checkerboard mapped onto the back wall through per-corner UVs: black checks draw black
/// (a zero albedo reflects nothing, whatever the light) and white ones as the untextured wall.
/// The upper wall is used, where no box stands in front of it and only indirect light reaches.
#[test]
fn albedo_maps_are_sampled_through_the_uvs() {
    let Some(ctx) = context() else { return };
    const CHECKS: u32 = 8;
    const TEXELS: u32 = 64;
    let rgba: Vec<u8> = (0..TEXELS * TEXELS)
        .flat_map(|i| {
            let (x, y) = (i % TEXELS, i / TEXELS);
            let per = TEXELS / CHECKS;
            let v = if (x / per + y / per).is_multiple_of(2) {
                255
            } else {
                0
            };
            [v, v, v, 255]
        })
        .collect();
    let plain = &cornell().scene;
    let (lo, hi) = plain.bounds().unwrap();
    let extent = hi - lo;
    let on_back_wall =
        |t: &bounce_core::scene::Triangle| t.positions.iter().all(|p| p.z - lo.z < 1e-3 * extent.z);
    assert!(plain.triangles.iter().any(on_back_wall));
    let uv = |p: Vec3| glam::Vec2::new((p.x - lo.x) / extent.x, (hi.y - p.y) / extent.y);
    let shading = Shading {
        triangles: plain
            .triangles
            .iter()
            .map(|t| TriangleShading {
                normals: [t.cross().normalize(); 3],
                uvs: t.positions.map(uv),
                tint: [t.albedo; 3],
                texture: on_back_wall(t).then_some(0),
            })
            .collect(),
        textures: vec![ShadingTexture {
            width: TEXELS,
            height: TEXELS,
            rgba,
            repeat_u: false,
            repeat_v: false,
        }],
    };
    let textured = Scene {
        shading: Some(shading),
        ..plain.clone()
    };
    let lights = spot();
    let options = RenderOptions {
        width: 320,
        height: 240,
        exposure: 4.0,
        indirect: true,
        direct: true,
    };
    let renderer = Renderer::new(ctx).unwrap();
    let volume = volume(&lights);
    let with = renderer
        .render(&textured, &camera(), &lights, &volume, &options)
        .unwrap();
    let without = renderer
        .render(plain, &camera(), &lights, &volume, &options)
        .unwrap();
    let (mut white, mut black) = (0, 0);
    for row in 0..2 {
        for column in 1..CHECKS - 1 {
            let centre = |c: u32| (c as f32 + 0.5) / CHECKS as f32;
            let p = Vec3::new(
                lo.x + centre(column) * extent.x,
                hi.y - centre(row) * extent.y,
                lo.z + 1e-3,
            );
            let textured = luminance(mean_rgb(&with, p, 2));
            let untextured = luminance(mean_rgb(&without, p, 2));
            eprintln!("check ({column}, {row}): {textured:.4} against {untextured:.4}");
            assert!(
                untextured > 0.005,
                "the upper back wall is lit: {untextured}"
            );
            if (column + row).is_multiple_of(2) {
                white += 1;
                assert!(
                    (textured - untextured).abs() <= 0.05 * untextured,
                    "white check ({column}, {row}): {textured} against {untextured}"
                );
            } else {
                black += 1;
                assert!(
                    textured <= 0.02 * untextured,
                    "black check ({column}, {row}): {textured} against {untextured}"
                );
            }
        }
    }
    assert_eq!((white, black), (6, 6));
}

/// The scene at `path` framed whole and drawn small with direct light and emission only (no
/// indirect light, so the volume is never read), under any light set: its linear pixels.
fn emission_pictures(ctx: &'static GpuContext, path: &Path) -> impl Fn(&LightSet) -> Vec<[f32; 3]> {
    let scene = import_path_with(path, &ImportOptions { shading: true }).unwrap();
    let camera = Camera::framing(scene.bounds().unwrap());
    let v = volume(&spot());
    let renderer = Renderer::new(ctx).unwrap();
    let options = RenderOptions {
        width: 96,
        height: 72,
        exposure: 1.0,
        indirect: false,
        direct: true,
    };
    move |lights: &LightSet| {
        renderer
            .render_linear(&scene, &camera, lights, &v, &options)
            .unwrap()
            .pixels
    }
}

/// A light set's emissive change redraws the surfaces of that material: the emissive Cornell
/// box's ceiling lamp (no other light, direct light and emission only) glows at the file's
/// emission, goes dark at strength 0 and red with a red colour; nothing else changes, and a
/// change naming a material the scene does not have is left out.
#[test]
fn emissive_changes_redraw_the_lamp() {
    let Some(ctx) = context() else { return };
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/cornell-box-emissive/CornellBox.glb");
    let draw = emission_pictures(ctx, &path);
    let lamp = |color: Option<[f32; 3]>, strength: Option<f32>| LightSet {
        lights: vec![Light::Emissive {
            material: Some("Emitter_Light_temp".into()),
            node: None,
            color,
            strength,
            name: None,
        }],
    };
    let file = draw(&LightSet::default());
    let off = draw(&lamp(None, Some(0.0)));
    let red = draw(&lamp(Some([1.0, 0.0, 0.0]), None));
    let glowing = file.iter().filter(|p| p[0] > 0.0).count();
    assert!(glowing > 20, "the lamp is in view: {glowing} pixels");
    for ((f, o), r) in file.iter().zip(&off).zip(&red) {
        assert_eq!(o[..3], [0.0; 3], "off: no light anywhere");
        assert_eq!(r[1..3], [0.0; 2], "red: no green or blue");
        assert!((r[0] - f[0]).abs() <= 1e-5 * f[0].max(1.0), "{r:?} {f:?}");
    }
    // A change naming no material of the scene is left out: the file's glow, nothing else.
    let bad = LightSet {
        lights: vec![Light::Emissive {
            material: Some("Lamp".into()),
            node: None,
            color: None,
            strength: Some(0.0),
            name: None,
        }],
    };
    assert_eq!(draw(&bad), file);
}

/// Two lamps sharing one material, told apart by node (the emissive box with its lamp placed
/// again lower, `bounce_testkit::scenes::two_lamps`): a change naming one node darkens that
/// lamp alone, and with emission the only light each pixel shows one lamp's glow, so the two
/// pictures with one lamp off add up to the file's.
#[test]
fn emissive_changes_by_node_redraw_one_lamp() {
    let Some(ctx) = context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let path = bounce_testkit::scenes::two_lamps(dir.path());
    let draw = emission_pictures(ctx, &path);
    let off = |node: &str| LightSet {
        lights: vec![Light::Emissive {
            material: None,
            node: Some(node.into()),
            color: None,
            strength: Some(0.0),
            name: None,
        }],
    };
    let file = draw(&LightSet::default());
    let first_off = draw(&off("Light"));
    let second_off = draw(&off("Lamp 2"));
    let glowing = |p: &[[f32; 3]]| p.iter().filter(|p| p[0] > 0.0).count();
    let (all, first, second) = (glowing(&file), glowing(&first_off), glowing(&second_off));
    assert!(
        first > 10 && second > 10 && first < all && second < all,
        "each lamp in view and darkened alone: {all} glowing, {first} with the first off, \
         {second} with the second off"
    );
    for ((f, a), b) in file.iter().zip(&first_off).zip(&second_off) {
        for c in 0..3 {
            assert!(
                (a[c] + b[c] - f[c]).abs() <= 1e-5 * f[c].max(1.0),
                "{a:?} + {b:?} against {f:?}"
            );
        }
    }
}
