//! The probe-lit sphere (issue 22): the Cornell box baked with probes, relit in-process under a
//! point light, a sphere ahead of a camera inside the box lit by the probes' ambient cube.

use std::sync::OnceLock;

use bounce_core::bake::{BakeOptions, NoProgress, bake_file};
use bounce_core::format::Baked;
use bounce_core::import::{ImportOptions, import_path_with};
use bounce_core::light::{Light, LightSet};
use bounce_core::probe::ProbeOptions;
use bounce_core::scene::Scene;
use bounce_core::voxel::Resolution;
use bounce_engine::{Engine, EngineChoice};
use bounce_render::{
    Camera, Image, ProbeSphere, Renderer, Stage, Terms, ambient_cube, volume_from_baked,
};
use glam::Vec3;

use super::{context, gltf, srgb};

struct Probed {
    scene: Scene,
    baked: Baked,
}

fn probed() -> &'static Probed {
    static BOX: OnceLock<Probed> = OnceLock::new();
    BOX.get_or_init(|| {
        let options = BakeOptions {
            resolution: Resolution::TargetPatches(300),
            rays: 512,
            probes: Some(ProbeOptions {
                rays: 256,
                ..ProbeOptions::default()
            }),
            ..BakeOptions::default()
        };
        Probed {
            scene: import_path_with(&gltf(), &ImportOptions { shading: true })
                .expect("importing the Cornell box"),
            baked: bake_file(&gltf(), &options, &NoProgress).expect("baking the Cornell box"),
        }
    })
}

fn point() -> LightSet {
    LightSet {
        lights: vec![Light::Point {
            position: [0.0, 1.5, 0.0],
            color: [1.0; 3],
            intensity: 10.0,
            range: None,
            name: None,
        }],
    }
}

/// Inside the box, looking at the back wall.
fn camera() -> Camera {
    Camera {
        eye: Vec3::new(0.0, 1.0, 0.9),
        target: Vec3::new(0.0, 1.0, -1.0),
        fov_y: 45f32.to_radians(),
    }
}

/// The box relit: a stage with its lights and indirect light, and the ambient cube the probes
/// give a sphere ahead of the camera.
fn lit_stage(renderer: &Renderer<'_>) -> (Stage, ProbeSphere) {
    let b = probed();
    let probes = b.baked.probes.as_ref().expect("the bake placed probes");
    assert!(!probes.positions.is_empty());
    let engine = Engine::new(EngineChoice::Cpu).unwrap();
    let loaded = engine.load(&b.baked).unwrap();
    let lit = engine.relight(&loaded, &[point()]).unwrap();
    let volume = volume_from_baked("cornell-box", &b.baked.layout, &lit[0].indirect).unwrap();
    let mut stage = Stage::new(renderer, &b.scene, &volume).unwrap();
    stage.set_lights(renderer, &point()).unwrap();
    let positions: Vec<Vec3> = probes.positions.iter().map(|&p| Vec3::from(p)).collect();
    let bounds = b.scene.bounds().unwrap();
    let placed = ProbeSphere::ahead_of(&camera(), bounds, [[0.0; 3]; 6]);
    let cube = ambient_cube(&positions, &lit[0].probes, placed.centre).expect("a cube");
    (stage, ProbeSphere { cube, ..placed })
}

/// Linear RGB of the pixel where a world point lands.
fn pixel(image: &Image, bounds: (Vec3, Vec3), p: Vec3) -> Vec3 {
    let aspect = image.width as f32 / image.height as f32;
    let ndc = camera()
        .view_proj(aspect, bounds)
        .unwrap()
        .project_point3(p);
    let x = ((ndc.x * 0.5 + 0.5) * image.width as f32) as u32;
    let y = ((0.5 - ndc.y * 0.5) * image.height as f32) as u32;
    let i = ((y * image.width + x) * 4) as usize;
    let px = &image.pixels[i..i + 3];
    Vec3::new(srgb(px[0]), srgb(px[1]), srgb(px[2]))
}

/// A channel's share of the colour.
fn share(c: Vec3, channel: usize) -> f32 {
    c[channel] / c.element_sum().max(1e-6)
}

/// The red wall is −X (its probes' −X side is red, the +X side green), and the sphere shows
/// it: its side towards −X is redder than its side towards +X, with and without direct light.
#[test]
fn the_probe_sphere_is_redder_on_the_red_walls_side() {
    let Some(ctx) = context() else { return };
    let renderer = Renderer::new(ctx).unwrap();
    let (mut stage, sphere) = lit_stage(&renderer);
    let [px, nx] = [sphere.cube[0], sphere.cube[1]].map(Vec3::from);
    eprintln!(
        "sphere at {} r {}: cube {:?}",
        sphere.centre, sphere.radius, sphere.cube
    );
    assert!(nx.x > nx.y && px.y > px.x, "−X {nx}, +X {px}");
    stage.set_probe_sphere(&renderer, Some(sphere));
    let bounds = stage.bounds();
    let left = sphere.centre - Vec3::X * sphere.radius * 0.8;
    let right = sphere.centre + Vec3::X * sphere.radius * 0.8;
    for direct in [false, true] {
        let terms = Terms {
            direct,
            indirect: true,
        };
        let image = renderer
            .render_stage(&mut stage, &camera(), 160, 120, 1.0, terms)
            .unwrap();
        let (l, r) = (pixel(&image, bounds, left), pixel(&image, bounds, right));
        eprintln!("direct {direct}: left {l}, right {r}");
        assert!(l.length() > 0.01 && r.length() > 0.01, "{l} {r}");
        // Redder towards the red wall, greener towards the green one.
        assert!(share(l, 0) > share(r, 0) + 0.02, "left {l}, right {r}");
        assert!(share(r, 1) > share(l, 1) + 0.02, "left {l}, right {r}");
    }
}

/// Without direct light the sphere is its probes' light alone: black where the cube is zero,
/// and `albedo / π · E` (tonemapped) under a cube of six equal sides `E`. Without a sphere the
/// same pixels show the box.
#[test]
fn the_probe_sphere_is_its_cubes_light_alone() {
    let Some(ctx) = context() else { return };
    let renderer = Renderer::new(ctx).unwrap();
    let (mut stage, sphere) = lit_stage(&renderer);
    let bounds = stage.bounds();
    let points = [
        sphere.centre,
        sphere.centre + Vec3::new(0.7, 0.0, 0.0) * sphere.radius,
        sphere.centre + Vec3::new(-0.5, 0.5, 0.0) * sphere.radius,
        sphere.centre + Vec3::new(0.0, -0.7, 0.0) * sphere.radius,
    ];
    let terms = Terms {
        direct: false,
        indirect: true,
    };
    let mut draw = |s: Option<ProbeSphere>| {
        stage.set_probe_sphere(&renderer, s);
        let image = renderer
            .render_stage(&mut stage, &camera(), 160, 120, 1.0, terms)
            .unwrap();
        points.map(|p| pixel(&image, bounds, p))
    };
    for c in draw(None) {
        assert!(c.length() > 0.01, "the box behind: {c}");
    }
    for c in draw(Some(ProbeSphere {
        cube: [[0.0; 3]; 6],
        ..sphere
    })) {
        assert_eq!(c, Vec3::ZERO);
    }
    let e = Vec3::new(1.0, 0.5, 2.0);
    let radiance = sphere.albedo * e / std::f32::consts::PI;
    let want = radiance / (Vec3::ONE + radiance);
    for c in draw(Some(ProbeSphere {
        cube: [e.to_array(); 6],
        ..sphere
    })) {
        assert!((c - want).abs().max_element() < 0.01, "{c} vs {want}");
    }
}
