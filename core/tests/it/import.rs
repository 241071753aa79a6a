//! glTF import: the repository's test scenes (`assets/`) (counts, materials, lights, bounds,
//! checked against the files through an independent reading with the `gltf` crate), and hand-made
//! files for each rule the importer enforces.

use std::path::{Path, PathBuf};

use bounce_core::import::{ImportError, import_path, import_slice};
use bounce_core::light::Light;
use bounce_core::scene::Scene;
use glam::{Mat3, Mat4, Vec3};
use serde_json::{Value, json};

// ---------------------------------------------------------------------------------------------
// The repository's scenes
// ---------------------------------------------------------------------------------------------

fn scenes_dir() -> PathBuf {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets");
    assert!(
        dir.join("README.md").is_file(),
        "test scenes not found at {} (the repository's assets/ folder)",
        dir.display()
    );
    dir
}

fn scene(file: &str) -> Scene {
    let path = scenes_dir().join(file);
    import_path(&path).unwrap_or_else(|e| panic!("importing {file}: {e}"))
}

struct Expected {
    file: &'static str,
    triangles: usize,
    lo: [f32; 3],
    hi: [f32; 3],
    tolerance: f32,
}

/// Triangle counts from the scenes' README; bounds in each scene's own units.
const SCENES: &[Expected] = &[
    // Metres-ish, y 0..1.99 (README); x and z from the file's accessor bounds under the node's
    // 90° rotation.
    Expected {
        file: "cornell-box/scene.gltf",
        triangles: 32,
        lo: [-1.02, 0.0, -1.04],
        hi: [1.0, 1.99, 0.99],
        tolerance: 1e-4,
    },
    // Millimetres: 0..556 wide, 548.8 high, 559.2 deep.
    Expected {
        file: "cornell-box-emissive/CornellBox.glb",
        triangles: 36,
        lo: [-556.0, 0.0, -559.2],
        hi: [0.0, 548.8, 0.0],
        tolerance: 1e-2,
    },
    // Cube 2 units, bbox from the README.
    Expected {
        file: "pandora/pandora.glb",
        triangles: 60_694,
        lo: [-736.0, 0.0, -416.0],
        hi: [736.0, 448.0, 416.0],
        tolerance: 1e-3,
    },
    // A 10 × 5 × 10 m room.
    Expected {
        file: "room-with-objects/room.glb",
        triangles: 63_720,
        lo: [-5.0, 0.0, -5.0],
        hi: [5.0, 5.0, 5.0],
        tolerance: 1e-4,
    },
    // Metres: a 3.1 m floor plane (scale 1.5535), the chair under 0.69 m.
    Expected {
        file: "sheen-chair-sun/MixedLightingExample.gltf",
        triangles: 40_898,
        lo: [-1.5535, -7.0e-5, -1.5535],
        hi: [1.5535, 0.6862, 1.5535],
        tolerance: 1e-3,
    },
    // Metres: a 40 m floor with 0.92 m walls, mirrored by the node's scale of −20.2.
    Expected {
        file: "small-room/IrradianceVolumeExample.glb",
        triangles: 32,
        lo: [-20.2003, -0.9231, -20.2003],
        hi: [20.3518, 0.0, 20.5025],
        tolerance: 1e-3,
    },
];

#[test]
fn every_repository_scene_imports_with_the_readme_counts_and_bounds() {
    for e in SCENES {
        let s = scene(e.file);
        let r = &s.report;
        assert_eq!(s.triangles.len(), e.triangles, "{}: triangles", e.file);
        assert_eq!(r.triangles, e.triangles, "{}: report.triangles", e.file);
        assert!(
            r.skipped_primitives.is_empty(),
            "{}: {:?}",
            e.file,
            r.skipped_primitives
        );
        assert_eq!(r.degenerate_triangles, 0, "{}", e.file);
        assert!(
            r.missing_textures.is_empty(),
            "{}: {:?}",
            e.file,
            r.missing_textures
        );
        assert!(r.warnings.is_empty(), "{}: {:?}", e.file, r.warnings);
        let (lo, hi) = s.bounds().expect("non-empty");
        for (got, want) in [(lo, e.lo), (hi, e.hi)] {
            assert!(
                (got - Vec3::from(want)).abs().max_element() < e.tolerance,
                "{}: bounds {lo} .. {hi}, expected {:?} .. {:?}",
                e.file,
                e.lo,
                e.hi
            );
        }
        for t in &s.triangles {
            assert!(t.area() > 0.0 && t.area().is_finite(), "{}", e.file);
            assert!(t.albedo.min_element() >= 0.0 && t.albedo.max_element() <= 1.0);
            assert!((t.material as usize) < s.materials.len());
        }
    }
}

#[test]
fn scene_triangles_match_an_independent_reading_of_the_files() {
    // Positions placed by the `gltf` crate's own node matrices, and the authored vertex normals
    // (by the inverse transpose) must agree with each imported triangle's winding, including
    // under small-room's mirroring scale of −20.2.
    for e in SCENES {
        let s = scene(e.file);
        let reference = reference_triangles(&scenes_dir().join(e.file));
        assert_eq!(reference.len(), s.triangles.len(), "{}", e.file);
        let scale = e.hi.iter().chain(&e.lo).fold(1f32, |m, v| m.max(v.abs()));
        let (mut with_normals, mut agree) = (0, 0);
        for (i, (t, (p, n))) in s.triangles.iter().zip(&reference).enumerate() {
            // Corner order may differ by the mirror swap: compare corners as sets.
            for q in t.positions {
                let d = p
                    .iter()
                    .map(|r| (q - *r).length())
                    .fold(f32::INFINITY, f32::min);
                assert!(
                    d < 1e-5 * scale,
                    "{} triangle {i}: {:?} vs {p:?}",
                    e.file,
                    t.positions
                );
            }
            if let Some(n) = n {
                with_normals += 1;
                if t.cross().dot(*n) > 0.0 {
                    agree += 1;
                }
            }
        }
        // Smooth normals may disagree with the face on a few sliver triangles (10 of the chair's
        // 40,898), never wholesale.
        assert!(
            agree as f64 >= 0.999 * with_normals as f64,
            "{}: {agree} of {with_normals} triangles face the way their authored normals do",
            e.file
        );
    }
}

type RefTriangle = ([Vec3; 3], Option<Vec3>);

/// World-space triangles of a file whose scene is a flat list of nodes (true of all the
/// repository's scenes), read with the `gltf` crate: corners, and the mean authored normal if there
/// is one.
fn reference_triangles(path: &Path) -> Vec<RefTriangle> {
    let bytes = std::fs::read(path).unwrap();
    // Without validation: the chair requires KHR_texture_transform, which this build of `gltf`
    // does not enable.
    let gltf = gltf::Gltf::from_slice_without_validation(&bytes).unwrap();
    let buffers = gltf::import_buffers(&gltf.document, path.parent(), gltf.blob.clone()).unwrap();
    let scene = gltf.document.default_scene().unwrap();
    let mut out = Vec::new();
    for node in scene.nodes() {
        assert_eq!(
            node.children().count(),
            0,
            "reference reader handles flat scenes only"
        );
        let Some(mesh) = node.mesh() else { continue };
        let m = Mat4::from_cols_array_2d(&node.transform().matrix());
        let normal_matrix = Mat3::from_mat4(m).inverse().transpose();
        for prim in mesh.primitives() {
            let reader = prim.reader(|b| Some(&buffers[b.index()]));
            let p: Vec<Vec3> = reader.read_positions().unwrap().map(Vec3::from).collect();
            let n: Option<Vec<Vec3>> = reader.read_normals().map(|n| n.map(Vec3::from).collect());
            let idx: Vec<u32> = reader.read_indices().unwrap().into_u32().collect();
            for t in idx.chunks_exact(3) {
                let [a, b, c] = [t[0], t[1], t[2]].map(|i| i as usize);
                let corners = [p[a], p[b], p[c]].map(|v| m.transform_point3(v));
                let normal = n.as_ref().map(|n| normal_matrix * (n[a] + n[b] + n[c]));
                out.push((corners, normal));
            }
        }
    }
    out
}

fn has_albedo(s: &Scene, want: [f32; 3]) -> usize {
    s.triangles
        .iter()
        .filter(|t| (t.albedo - Vec3::from(want)).abs().max_element() < 1e-4)
        .count()
}

#[test]
fn cornell_box_has_mcguires_albedos_and_no_emission() {
    let s = scene("cornell-box/scene.gltf");
    // Floor, ceiling, back wall and both boxes (2 + 2 + 2 + 10 + 10) are white.
    assert_eq!(has_albedo(&s, [0.725, 0.71, 0.68]), 26);
    assert_eq!(has_albedo(&s, [0.63, 0.065, 0.05]), 2, "red left wall");
    assert_eq!(has_albedo(&s, [0.14, 0.45, 0.091]), 2, "green right wall");
    assert_eq!(has_albedo(&s, [0.78, 0.78, 0.78]), 2, "light quad");
    assert!(
        s.triangles
            .iter()
            .all(|t| t.emission == Vec3::ZERO && t.double_sided)
    );
    assert!(s.lights.is_empty());
    let names: Vec<&str> = s.materials.iter().map(|m| m.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "floor",
            "ceiling",
            "backWall",
            "rightWall",
            "leftWall",
            "shortBox",
            "tallBox",
            "light"
        ]
    );
    let red = &s.materials[4];
    assert_eq!(red.base_color_factor, [0.63, 0.065, 0.05]);
    assert!(red.double_sided && !red.has_base_color_texture);
    // Each triangle points at its own material.
    for t in &s.triangles {
        let m = &s.materials[t.material as usize];
        assert_eq!(t.albedo, Vec3::from(m.base_color_factor));
    }
}

#[test]
fn emissive_cornell_box_applies_emissive_strength() {
    let s = scene("cornell-box-emissive/CornellBox.glb");
    let emitters: Vec<_> = s
        .triangles
        .iter()
        .filter(|t| t.emission != Vec3::ZERO)
        .collect();
    assert_eq!(emitters.len(), 2, "one emissive quad");
    for t in &emitters {
        // emissiveFactor [1, 1, 1] × emissiveStrength 100.
        assert_eq!(t.emission, Vec3::splat(100.0));
        assert_eq!(s.materials[t.material as usize].name, "Emitter_Light_temp");
        // Just under the 548.8 mm ceiling.
        assert!(t.centroid().y > 540.0, "{}", t.centroid());
    }
    assert_eq!(s.materials[0].emission, [100.0; 3]);
    assert_eq!(has_albedo(&s, [0.5, 0.0, 0.0]), 2, "red wall");
    assert_eq!(has_albedo(&s, [0.0, 0.5, 0.0]), 2, "green wall");
}

/// Linear mean of an sRGB image file, computed independently of the importer.
fn linear_mean(path: &Path) -> Vec3 {
    let img = image::open(path).unwrap().into_rgb8();
    let to_linear = |c: u8| {
        let c = f64::from(c) / 255.0;
        if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        }
    };
    let mut sum = [0f64; 3];
    for p in img.pixels() {
        for (s, &c) in sum.iter_mut().zip(&p.0) {
            *s += to_linear(c);
        }
    }
    let n = f64::from(img.width() * img.height());
    Vec3::new(
        (sum[0] / n) as f32,
        (sum[1] / n) as f32,
        (sum[2] / n) as f32,
    )
}

fn mean_albedo(s: &Scene, material: &str) -> (usize, Vec3) {
    let tris: Vec<_> = s
        .triangles
        .iter()
        .filter(|t| s.materials[t.material as usize].name == material)
        .collect();
    let n = tris.len();
    (
        n,
        tris.iter().map(|t| t.albedo).sum::<Vec3>() / n.max(1) as f32,
    )
}

#[test]
fn sheen_chair_has_the_sun_and_textured_albedo() {
    let s = scene("sheen-chair-sun/MixedLightingExample.gltf");
    let dir = scenes_dir().join("sheen-chair-sun");

    assert_eq!(s.report.lights, 1);
    let [
        Light::Directional {
            direction,
            color,
            intensity,
            name,
        },
    ] = s.lights.as_slice()
    else {
        panic!("expected one directional light, got {:?}", s.lights);
    };
    assert_eq!(name.as_deref(), Some("Sun"));
    assert_eq!(*intensity, 2049.0);
    assert_eq!(*color, [1.0, 1.0, 1.0]);
    // The Sun node's rotation (-0.4886, 0.1165, -0.2006, 0.8411) applied to -Z.
    let want = Vec3::new(-0.392_076, -0.775_170, -0.495_367);
    assert!(
        (Vec3::from(*direction) - want).length() < 1e-4,
        "{direction:?}"
    );

    // The mango fabric (factor 1, the default variant) takes its colour from the texture: its
    // mean is the image's linear mean, nothing like the white factor.
    let fabric = &s.materials[2];
    assert_eq!(fabric.name, "fabric Mystere Mango Velvet");
    assert!(fabric.has_base_color_texture);
    assert_eq!(fabric.base_color_factor, [1.0; 3]);
    let (n, mean) = mean_albedo(&s, "fabric Mystere Mango Velvet");
    assert_eq!(n, 26_176);
    let image = linear_mean(&dir.join("SheenChairBaseColor.jpg"));
    assert!(
        (mean - image).abs().max_element() < 0.01,
        "{mean} vs image {image}"
    );
    assert!(
        mean.y < 0.05,
        "textured albedo {mean} must differ from the white factor"
    );

    // The label's texture varies; its triangles' albedos vary with it.
    let label: Vec<Vec3> = s
        .triangles
        .iter()
        .filter(|t| s.materials[t.material as usize].name == "label")
        .map(|t| t.albedo)
        .collect();
    let (lo, hi) = label.iter().fold((Vec3::ONE, Vec3::ZERO), |(lo, hi), a| {
        (lo.min(*a), hi.max(*a))
    });
    assert!(hi.x - lo.x > 0.1, "label albedo range {lo} .. {hi}");
    let label_image = linear_mean(&dir.join("SheenChairLabelBaseColor.jpg"));
    assert!(hi.x > label_image.x * 0.8 && lo.x < label_image.x * 1.2);

    // Wood: the texture (with its KHR_texture_transform) times a factor of 1 (brown) or 0.036
    // (black). The black variant is not the default, so only brown triangles exist.
    let (n, brown) = mean_albedo(&s, "wood Brown");
    assert_eq!(n, 9_792);
    let wood = linear_mean(&dir.join("SheenChairWoodBaseColor.jpg"));
    assert!(
        (brown - wood).abs().max_element() < 0.03,
        "{brown} vs image {wood}"
    );

    // Untextured materials keep their factor exactly.
    assert_eq!(has_albedo(&s, [0.28, 0.26, 0.23]), 3_840, "metal");
}

// ---------------------------------------------------------------------------------------------
// Hand-made files
// ---------------------------------------------------------------------------------------------

/// Builds a glTF document with one embedded (data URI) buffer.
#[derive(Default)]
pub(crate) struct Gltf {
    bin: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl Gltf {
    pub(crate) fn view(&mut self, bytes: &[u8]) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        self.views
            .push(json!({"buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len()}));
        self.bin.extend_from_slice(bytes);
        self.views.len() - 1
    }

    pub(crate) fn floats(&mut self, values: &[f32], ty: &str) -> usize {
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let dims = match ty {
            "VEC2" => 2,
            "VEC3" => 3,
            _ => 4,
        };
        let view = self.view(&bytes);
        self.accessors.push(json!({
            "bufferView": view, "componentType": 5126, "count": values.len() / dims, "type": ty
        }));
        self.accessors.len() - 1
    }

    pub(crate) fn positions(&mut self, p: &[[f32; 3]]) -> usize {
        self.floats(&p.concat(), "VEC3")
    }

    pub(crate) fn uvs(&mut self, uv: &[[f32; 2]]) -> usize {
        self.floats(&uv.concat(), "VEC2")
    }

    pub(crate) fn indices(&mut self, i: &[u16]) -> usize {
        let bytes: Vec<u8> = i.iter().flat_map(|v| v.to_le_bytes()).collect();
        let view = self.view(&bytes);
        self.accessors.push(json!({
            "bufferView": view, "componentType": 5123, "count": i.len(), "type": "SCALAR"
        }));
        self.accessors.len() - 1
    }

    /// The finished JSON: `doc` plus `asset`, the buffer, its views and accessors.
    pub(crate) fn json(self, mut doc: Value) -> Vec<u8> {
        let o = doc.as_object_mut().unwrap();
        o.insert("asset".into(), json!({"version": "2.0"}));
        o.insert(
            "buffers".into(),
            json!([{
                "byteLength": self.bin.len(),
                "uri": format!("data:application/octet-stream;base64,{}", base64(&self.bin))
            }]),
        );
        o.insert("bufferViews".into(), Value::Array(self.views));
        o.insert("accessors".into(), Value::Array(self.accessors));
        serde_json::to_vec(&doc).unwrap()
    }

    /// The same as a GLB, the buffer in the BIN chunk.
    pub(crate) fn glb(self, mut doc: Value) -> Vec<u8> {
        let mut bin = self.bin;
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        let o = doc.as_object_mut().unwrap();
        o.insert("asset".into(), json!({"version": "2.0"}));
        o.insert("buffers".into(), json!([{"byteLength": bin.len()}]));
        o.insert("bufferViews".into(), Value::Array(self.views));
        o.insert("accessors".into(), Value::Array(self.accessors));
        let mut json = serde_json::to_vec(&doc).unwrap();
        while !json.len().is_multiple_of(4) {
            json.push(b' ');
        }
        let total = 12 + 8 + json.len() + 8 + bin.len();
        let mut out = b"glTF".to_vec();
        out.extend(2u32.to_le_bytes());
        out.extend((total as u32).to_le_bytes());
        out.extend((json.len() as u32).to_le_bytes());
        out.extend(b"JSON");
        out.extend(json);
        out.extend((bin.len() as u32).to_le_bytes());
        out.extend(b"BIN\0");
        out.extend(bin);
        out
    }
}

fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for i in 0..4 {
            if i <= chunk.len() {
                s.push(A[(n >> (18 - 6 * i) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

/// One triangle in the z = 0 plane, counter-clockwise seen from +z (normal +z).
const TRI: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];

fn import_json(bytes: &[u8]) -> Scene {
    import_slice(bytes, None).unwrap_or_else(|e| panic!("{e}"))
}

fn assert_close(a: Vec3, b: Vec3) {
    assert!((a - b).length() < 1e-5, "{a} vs {b}");
}

#[test]
fn node_transforms_compose_down_the_hierarchy() {
    let mut g = Gltf::default();
    let pos = g.positions(&TRI);
    let (s, c) = (
        std::f32::consts::FRAC_PI_4.sin(),
        std::f32::consts::FRAC_PI_4.cos(),
    );
    let doc = g.json(json!({
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [
            // Parent as a matrix: uniform scale 2, then translate (10, 0, 0).
            {"matrix": [2,0,0,0, 0,2,0,0, 0,0,2,0, 10,0,0,1], "children": [1]},
            // Child as TRS: scale 3, rotate 90° about +z, translate (0, 1, 0).
            {"translation": [0, 1, 0], "rotation": [0, 0, s, c], "scale": [3, 3, 3], "mesh": 0}
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": pos}}]}]
    }));
    let scene = import_json(&doc);
    let [t] = scene.triangles.as_slice() else {
        panic!("{:?}", scene.triangles)
    };
    // p -> 2 (R(3p) + (0, 1, 0)) + (10, 0, 0).
    assert_close(t.positions[0], Vec3::new(10.0, 2.0, 0.0));
    assert_close(t.positions[1], Vec3::new(10.0, 8.0, 0.0));
    assert_close(t.positions[2], Vec3::new(4.0, 2.0, 0.0));
    assert!(t.cross().z > 0.0);
    // No material: glTF's default, white and one-sided.
    assert_eq!(t.albedo, Vec3::ONE);
    assert!(!t.double_sided);
    assert_eq!(scene.materials[t.material as usize].name, "default");
    assert_eq!((scene.report.meshes, scene.report.primitives), (1, 1));
}

#[test]
fn mirroring_nodes_keep_the_authored_facing() {
    let mut g = Gltf::default();
    let pos = g.positions(&TRI);
    let doc = g.json(json!({
        "scenes": [{"nodes": [0, 1, 2]}],
        "nodes": [
            {"mesh": 0},
            // A mirror across x = 0: the face still points +z.
            {"mesh": 0, "scale": [-1, 1, 1], "translation": [0, 0, 5]},
            // A mirror across z = 0: the face now points -z.
            {"mesh": 0, "scale": [1, 1, -1], "translation": [0, 0, 10]}
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": pos}}]}]
    }));
    let scene = import_json(&doc);
    let n: Vec<Vec3> = scene
        .triangles
        .iter()
        .map(|t| t.cross().normalize())
        .collect();
    assert_eq!(n.len(), 3);
    assert_close(n[0], Vec3::Z);
    assert_close(n[1], Vec3::Z);
    assert_close(n[2], -Vec3::Z);
    assert_close(
        scene.triangles[1].centroid(),
        Vec3::new(-1.0 / 3.0, 1.0 / 3.0, 5.0),
    );
    // One mesh instanced three times counts once.
    assert_eq!(scene.report.meshes, 1);
}

#[test]
fn strips_and_fans_become_consistently_wound_triangles() {
    let mut g = Gltf::default();
    // A unit square as a strip (0, 1, 2, 3 zig-zag) and as a fan around corner 0.
    let strip = g.positions(&[
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
    ]);
    let fan = g.positions(&[
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
    ]);
    let idx = g.indices(&[0, 1, 2, 3]);
    let doc = g.json(json!({
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [
            {"attributes": {"POSITION": strip}, "mode": 5},
            {"attributes": {"POSITION": fan}, "indices": idx, "mode": 6}
        ]}]
    }));
    // No `scenes` at all: every root node is imported.
    let scene = import_json(&doc);
    assert_eq!(scene.triangles.len(), 4);
    for t in &scene.triangles {
        assert_close(t.cross(), Vec3::Z);
    }
    assert!((scene.total_area() - 2.0).abs() < 1e-6);
}

#[test]
fn line_primitives_are_skipped_and_reported() {
    let mut g = Gltf::default();
    let pos = g.positions(&TRI);
    let doc = g.json(json!({
        "nodes": [{"mesh": 0}],
        "meshes": [{"name": "wire", "primitives": [
            {"attributes": {"POSITION": pos}},
            {"attributes": {"POSITION": pos}, "mode": 1},
            {"attributes": {}}
        ]}]
    }));
    let scene = import_json(&doc);
    assert_eq!(scene.triangles.len(), 1);
    assert_eq!(scene.report.primitives, 3);
    let skipped = &scene.report.skipped_primitives;
    assert_eq!(skipped.len(), 2, "{skipped:?}");
    assert!(
        skipped[0].contains("'wire'") && skipped[0].contains("primitive 1"),
        "{}",
        skipped[0]
    );
    assert!(skipped[0].contains("Lines"), "{}", skipped[0]);
    assert!(
        skipped[1].contains("primitive 2") && skipped[1].contains("POSITION"),
        "{}",
        skipped[1]
    );
}

#[test]
fn only_lines_is_no_triangles_and_says_why() {
    let mut g = Gltf::default();
    let pos = g.positions(&TRI);
    let doc = g.json(json!({
        "nodes": [{"mesh": 0}],
        "meshes": [{"name": "wire", "primitives": [{"attributes": {"POSITION": pos}, "mode": 3}]}]
    }));
    let err = import_slice(&doc, None).unwrap_err();
    assert!(matches!(err, ImportError::NoTriangles { .. }), "{err:?}");
    let msg = err.to_string();
    assert!(msg.contains("LineStrip") && msg.contains("'wire'"), "{msg}");
}

#[test]
fn degenerate_triangles_are_dropped_and_counted() {
    let mut g = Gltf::default();
    let pos = g.positions(&[
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [2.0, 0.0, 0.0],
    ]);
    // A good triangle, a collinear one, one with a repeated corner.
    let idx = g.indices(&[0, 1, 2, 0, 1, 3, 2, 2, 1]);
    let doc = g.json(json!({
        "nodes": [{"mesh": 0}, {"mesh": 0, "scale": [1, 0, 1]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": pos}, "indices": idx}]}]
    }));
    let scene = import_json(&doc);
    assert_eq!(scene.triangles.len(), 1);
    // Two in the first instance, all three in the flattened second.
    assert_eq!(scene.report.degenerate_triangles, 5);
}

#[test]
fn a_nan_position_is_an_error_naming_mesh_and_primitive() {
    let mut g = Gltf::default();
    let good = g.positions(&TRI);
    let bad = g.positions(&[[0.0, 0.0, 0.0], [f32::NAN, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    let doc = g.json(json!({
        "nodes": [{"mesh": 0}],
        "meshes": [{"name": "broken", "primitives": [
            {"attributes": {"POSITION": good}},
            {"attributes": {"POSITION": bad}}
        ]}]
    }));
    let err = import_slice(&doc, None).unwrap_err();
    let ImportError::NonFinitePosition {
        mesh,
        primitive,
        vertex,
        ..
    } = &err
    else {
        panic!("{err:?}");
    };
    assert!(mesh.contains("broken"), "{mesh}");
    assert_eq!((*primitive, *vertex), (1, 1));
    assert!(err.to_string().contains("non-finite"), "{err}");
}

#[test]
fn not_gltf_bytes_are_not_gltf() {
    for bytes in [
        &b"hello, world"[..],
        b"{}",
        b"",
        b"glTF\x02\0\0\0\x04\0\0\0",
    ] {
        let err = import_slice(bytes, None).unwrap_err();
        let ImportError::NotGltf { reason, .. } = &err else {
            panic!("{bytes:?}: {err:?}");
        };
        assert!(!reason.is_empty());
    }
    let err = import_slice(br#"{"asset": {"version": "1.0"}}"#, None).unwrap_err();
    assert!(err.to_string().contains("1.0"), "{err}");
    // An attribute naming an accessor that does not exist (the `gltf` crate's validator would
    // index out of bounds on this one).
    let dangling = br#"{"asset": {"version": "2.0"}, "nodes": [{"mesh": 0}],
                        "meshes": [{"primitives": [{"attributes": {"POSITION": 5}}]}]}"#;
    let err = import_slice(dangling, None).unwrap_err();
    assert!(
        matches!(&err, ImportError::NotGltf { reason, .. } if reason.contains("POSITION") && reason.contains("accessor 5")),
        "{err}"
    );
}

#[test]
fn a_missing_path_is_not_found() {
    let err = import_path(Path::new("/nonexistent/scene.gltf")).unwrap_err();
    assert!(matches!(err, ImportError::NotFound { .. }), "{err:?}");
    assert!(err.to_string().contains("/nonexistent/scene.gltf"));
}

#[test]
fn required_extensions_that_change_geometry_are_refused() {
    let doc = br#"{"asset": {"version": "2.0"}, "extensionsUsed": ["KHR_draco_mesh_compression"],
                   "extensionsRequired": ["KHR_draco_mesh_compression"]}"#;
    let err = import_slice(doc, None).unwrap_err();
    assert!(
        matches!(&err, ImportError::UnsupportedExtensions { extensions, .. } if extensions == &["KHR_draco_mesh_compression"]),
        "{err:?}"
    );
}

#[test]
fn a_missing_buffer_file_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let doc = json!({
        "asset": {"version": "2.0"},
        "buffers": [{"uri": "geometry.bin", "byteLength": 36}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}]
    });
    let path = dir.path().join("scene.gltf");
    std::fs::write(&path, serde_json::to_vec(&doc).unwrap()).unwrap();
    let err = import_path(&path).unwrap_err();
    assert!(
        matches!(err, ImportError::Buffer { buffer: 0, .. }),
        "{err:?}"
    );
    assert!(err.to_string().contains("geometry.bin"), "{err}");
    // Once the file is there, the same scene imports.
    let bytes: Vec<u8> = TRI.concat().iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(dir.path().join("geometry.bin"), bytes).unwrap();
    assert_eq!(import_path(&path).unwrap().triangles.len(), 1);
}

#[test]
fn bad_accessors_skip_their_primitive_with_a_reason() {
    let mut g = Gltf::default();
    let pos = g.positions(&TRI);
    let out_of_range = g.indices(&[0, 1, 7]);
    let doc = json!({
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [
            {"attributes": {"POSITION": pos}},
            {"attributes": {"POSITION": pos}, "indices": out_of_range},
            {"attributes": {"POSITION": 2}}
        ]}]
    });
    // Accessor 2 claims more vertices than its buffer view holds.
    let mut bytes: Value = serde_json::from_slice(&g.json(doc)).unwrap();
    bytes["accessors"]
        .as_array_mut()
        .unwrap()
        .push(json!({"bufferView": 0, "componentType": 5126, "count": 1000, "type": "VEC3"}));
    let scene = import_json(&serde_json::to_vec(&bytes).unwrap());
    assert_eq!(scene.triangles.len(), 1);
    let skipped = &scene.report.skipped_primitives;
    assert_eq!(skipped.len(), 2, "{skipped:?}");
    assert!(
        skipped[0].contains("index 7 out of range"),
        "{}",
        skipped[0]
    );
    assert!(skipped[1].contains("runs past the end"), "{}", skipped[1]);
}

#[test]
fn vertex_colours_and_factor_multiply_into_the_albedo() {
    let mut g = Gltf::default();
    let pos = g.positions(&TRI);
    // RGBA per vertex; the triangle's mean colour is (1, 0.5, 0) and alpha is ignored.
    let col = g.floats(
        &[1.0, 0.25, 0.0, 0.3, 1.0, 0.5, 0.0, 1.0, 1.0, 0.75, 0.0, 0.0],
        "VEC4",
    );
    let doc = g.json(json!({
        "nodes": [{"mesh": 0}],
        "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.8, 1.0, 1.0]},
                       "emissiveFactor": [0.25, 0.5, 1.0]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": pos, "COLOR_0": col}, "material": 0}]}]
    }));
    let scene = import_json(&doc);
    let t = scene.triangles[0];
    assert_close(t.albedo, Vec3::new(0.5, 0.4, 0.0));
    // Emission is not tinted by vertex colour; no strength extension means 1.
    assert_close(t.emission, Vec3::new(0.25, 0.5, 1.0));
}

/// Writes an sRGB PNG of `pixels` (row-major, top row first) into `dir`.
fn write_png(dir: &Path, name: &str, width: u32, pixels: &[[u8; 3]]) {
    let height = pixels.len() as u32 / width;
    let img = image::RgbImage::from_raw(width, height, pixels.concat()).unwrap();
    img.save(dir.join(name)).unwrap();
}

/// One triangle with the given UVs, a base-colour texture `image_uri` and a factor.
fn textured_triangle(
    uv: [[f32; 2]; 3],
    image_uri: &str,
    factor: [f32; 4],
    sampler: Value,
) -> Value {
    let mut g = Gltf::default();
    let pos = g.positions(&TRI);
    let uv = g.uvs(&uv);
    let bytes = g.json(json!({
        "nodes": [{"mesh": 0}],
        "materials": [{"name": "painted", "pbrMetallicRoughness": {
            "baseColorFactor": factor, "baseColorTexture": {"index": 0}}}],
        "textures": [{"source": 0, "sampler": 0}],
        "samplers": [sampler],
        "images": [{"uri": image_uri}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": pos, "TEXCOORD_0": uv}, "material": 0}]}]
    }));
    serde_json::from_slice(&bytes).unwrap()
}

fn import_in(dir: &Path, doc: &Value) -> Scene {
    let path = dir.join("scene.gltf");
    std::fs::write(&path, serde_json::to_vec(doc).unwrap()).unwrap();
    import_path(&path).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn a_missing_texture_is_reported_and_the_factor_used() {
    let dir = tempfile::tempdir().unwrap();
    let doc = textured_triangle(
        [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
        "does-not-exist.png",
        [0.5, 0.25, 1.0, 1.0],
        json!({}),
    );
    let scene = import_in(dir.path(), &doc);
    assert_eq!(scene.triangles[0].albedo, Vec3::new(0.5, 0.25, 1.0));
    let missing = &scene.report.missing_textures;
    assert_eq!(missing.len(), 1, "{missing:?}");
    assert!(missing[0].contains("does-not-exist.png"), "{}", missing[0]);
    assert!(scene.materials[0].has_base_color_texture);

    // Undecodable bytes are reported the same way.
    std::fs::write(dir.path().join("does-not-exist.png"), b"not a png").unwrap();
    let scene = import_in(dir.path(), &doc);
    assert_eq!(scene.report.missing_textures.len(), 1);
    assert_eq!(scene.triangles[0].albedo, Vec3::new(0.5, 0.25, 1.0));
}

/// Found by the `gltf_import` fuzz target (issue 19): an image with neither a `uri` nor a
/// `bufferView`, or a `bufferView` without a `mimeType`, passes glTF validation and panicked in
/// the `gltf` crate. Now it is a missing texture like any other.
#[test]
fn an_image_with_no_source_or_no_mime_type_is_reported_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let mut doc = textured_triangle(
        [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
        "unused.png",
        [0.5, 0.25, 1.0, 1.0],
        json!({}),
    );
    for (image, says) in [
        (json!({}), "neither a uri nor a bufferView"),
        (json!({"bufferView": 0}), "a bufferView but no mimeType"),
    ] {
        doc["images"] = json!([image]);
        let scene = import_in(dir.path(), &doc);
        assert_eq!(scene.triangles[0].albedo, Vec3::new(0.5, 0.25, 1.0));
        let missing = &scene.report.missing_textures;
        assert_eq!(missing.len(), 1, "{missing:?}");
        assert!(missing[0].contains(says), "{}", missing[0]);
    }
}

#[test]
fn texture_is_srgb_decoded_averaged_over_the_footprint_and_times_the_factor() {
    let dir = tempfile::tempdir().unwrap();
    // 2×2: top row red | blue, bottom row sRGB grey 188 (linear 0.5029) | black.
    let grey = 188;
    write_png(
        dir.path(),
        "quad.png",
        2,
        &[[255, 0, 0], [0, 0, 255], [grey, grey, grey], [0, 0, 0]],
    );
    let clamp = json!({"wrapS": 33071, "wrapT": 33071, "magFilter": 9728});
    let linear_grey = ((f32::from(grey) / 255.0 + 0.055) / 1.055).powf(2.4);

    // Inside the top-left texel only (UV origin is the image's top-left corner).
    let red = textured_triangle(
        [[0.05, 0.05], [0.4, 0.05], [0.05, 0.4]],
        "quad.png",
        [1.0; 4],
        clamp.clone(),
    );
    assert_close(
        import_in(dir.path(), &red).triangles[0].albedo,
        Vec3::new(1.0, 0.0, 0.0),
    );

    // Inside the bottom-left texel, times a factor of 0.5.
    let g = textured_triangle(
        [[0.05, 0.6], [0.4, 0.6], [0.05, 0.95]],
        "quad.png",
        [0.5, 0.5, 0.5, 1.0],
        clamp.clone(),
    );
    assert_close(
        import_in(dir.path(), &g).triangles[0].albedo,
        Vec3::splat(0.5 * linear_grey),
    );

    // A footprint symmetric across a sharp red | blue edge averages to about half of each.
    let halves: Vec<[u8; 3]> = (0..16 * 16)
        .map(|i| if i % 16 < 8 { [255, 0, 0] } else { [0, 0, 255] })
        .collect();
    write_png(dir.path(), "halves.png", 16, &halves);
    let across = textured_triangle(
        [[0.0, 0.0], [1.0, 0.0], [0.5, 0.5]],
        "halves.png",
        [1.0; 4],
        json!({}),
    );
    let a = import_in(dir.path(), &across).triangles[0].albedo;
    assert!(
        a.y == 0.0 && (a.x + a.z - 1.0).abs() < 1e-4 && (a.x - 0.5).abs() < 0.1,
        "{a}"
    );

    // Repeat wrapping (the default): UVs shifted by whole tiles sample the same texel.
    let shifted = textured_triangle(
        [[3.05, -1.95], [3.4, -1.95], [3.05, -1.6]],
        "quad.png",
        [1.0; 4],
        json!({"magFilter": 9728}),
    );
    assert_close(
        import_in(dir.path(), &shifted).triangles[0].albedo,
        Vec3::new(1.0, 0.0, 0.0),
    );

    // An embedded (data URI) PNG imports without any base directory.
    let png = std::fs::read(dir.path().join("quad.png")).unwrap();
    let embedded = textured_triangle(
        [[0.05, 0.05], [0.4, 0.05], [0.05, 0.4]],
        &format!("data:image/png;base64,{}", base64(&png)),
        [1.0; 4],
        clamp,
    );
    let scene = import_slice(&serde_json::to_vec(&embedded).unwrap(), None).unwrap();
    assert_close(scene.triangles[0].albedo, Vec3::new(1.0, 0.0, 0.0));
    assert!(scene.report.missing_textures.is_empty());
}

#[test]
fn texture_transform_moves_the_lookup() {
    let dir = tempfile::tempdir().unwrap();
    write_png(dir.path(), "lr.png", 2, &[[255, 0, 0], [0, 0, 255]]);
    // UVs in the left (red) half, offset by half the texture: blue.
    let mut doc = textured_triangle(
        [[0.05, 0.1], [0.4, 0.1], [0.05, 0.9]],
        "lr.png",
        [1.0; 4],
        json!({"wrapS": 33071, "wrapT": 33071, "magFilter": 9728}),
    );
    doc["extensionsUsed"] = json!(["KHR_texture_transform"]);
    doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["extensions"] =
        json!({"KHR_texture_transform": {"offset": [0.5, 0.0]}});
    let scene = import_in(dir.path(), &doc);
    assert_close(scene.triangles[0].albedo, Vec3::new(0.0, 0.0, 1.0));
    assert!(
        scene.report.warnings.is_empty(),
        "{:?}",
        scene.report.warnings
    );
}

#[test]
fn punctual_lights_are_placed_in_world_space_and_invalid_ones_skipped() {
    let mut g = Gltf::default();
    let pos = g.positions(&TRI);
    let (s, c) = (
        std::f32::consts::FRAC_PI_4.sin(),
        std::f32::consts::FRAC_PI_4.cos(),
    );
    let doc = g.json(json!({
        "extensionsUsed": ["KHR_lights_punctual"],
        "extensions": {"KHR_lights_punctual": {"lights": [
            {"type": "point", "name": "bulb", "color": [1, 0.5, 0.25], "intensity": 40, "range": 12},
            {"type": "spot", "intensity": 100, "spot": {"innerConeAngle": 0.2, "outerConeAngle": 0.5}},
            {"type": "point", "name": "negative", "intensity": -1},
            {"type": "area", "name": "unknown"},
            {"type": "directional", "name": "unplaced"},
            {"type": "spot", "name": "coneless"}
        ]}},
        "scenes": [{"nodes": [0]}],
        "nodes": [
            {"translation": [0, 3, 0], "scale": [2, 2, 2], "children": [1, 2, 3, 4, 5, 6], "mesh": 0},
            {"translation": [1, 0, 0], "extensions": {"KHR_lights_punctual": {"light": 0}}},
            // Rotated -90° about x: its -Z axis points down.
            {"rotation": [-s, 0, 0, c], "extensions": {"KHR_lights_punctual": {"light": 1}}},
            {"extensions": {"KHR_lights_punctual": {"light": 2}}},
            {"name": "holder", "extensions": {"KHR_lights_punctual": {"light": 3}}},
            {"name": "dangling", "extensions": {"KHR_lights_punctual": {"light": 99}}},
            {"extensions": {"KHR_lights_punctual": {"light": 5}}}
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": pos}}]}]
    }));
    let scene = import_json(&doc);
    assert_eq!(scene.report.lights, 2);
    assert_eq!(
        scene.lights[0],
        Light::Point {
            position: [2.0, 3.0, 0.0],
            color: [1.0, 0.5, 0.25],
            intensity: 40.0,
            range: Some(12.0),
            name: Some("bulb".into()),
        }
    );
    let Light::Spot {
        position,
        direction,
        inner_cone_angle,
        outer_cone_angle,
        name,
        ..
    } = &scene.lights[1]
    else {
        panic!("{:?}", scene.lights[1]);
    };
    assert_close(Vec3::from(*position), Vec3::new(0.0, 3.0, 0.0));
    assert_close(Vec3::from(*direction), -Vec3::Y);
    assert_eq!((*inner_cone_angle, *outer_cone_angle), (0.2, 0.5));
    assert_eq!(name, &None);
    let skipped = &scene.report.skipped_lights;
    assert_eq!(skipped.len(), 5, "{skipped:?}");
    assert!(
        skipped[0].contains("negative") && skipped[0].contains("intensity"),
        "{}",
        skipped[0]
    );
    assert!(
        skipped[1].contains("'unknown'") && skipped[1].contains("unknown light type"),
        "{}",
        skipped[1]
    );
    assert!(
        skipped[2].contains("'dangling'") && skipped[2].contains("light 99 does not exist"),
        "{}",
        skipped[2]
    );
    assert!(
        skipped[3].contains("'coneless'") && skipped[3].contains("cone"),
        "{}",
        skipped[3]
    );
    assert!(
        skipped[4].contains("'unplaced'") && skipped[4].contains("not placed"),
        "{}",
        skipped[4]
    );
}

#[test]
fn glb_container_imports_like_the_json() {
    let mut g = Gltf::default();
    let pos = g.positions(&TRI);
    let idx = g.indices(&[0, 1, 2]);
    let glb = g.glb(json!({
        "nodes": [{"mesh": 0, "translation": [0, 0, 1]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": pos}, "indices": idx}]}]
    }));
    let scene = import_slice(&glb, None).unwrap();
    assert_eq!(scene.triangles.len(), 1);
    assert_close(scene.triangles[0].positions[1], Vec3::new(1.0, 0.0, 1.0));
}

#[test]
fn corrupted_glb_never_panics() {
    let mut g = Gltf::default();
    let pos = g.positions(&TRI);
    let uv = g.uvs(&[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]);
    let idx = g.indices(&[0, 1, 2]);
    let glb = g.glb(json!({
        "nodes": [{"mesh": 0, "children": [1]}, {"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": pos, "TEXCOORD_0": uv}, "indices": idx}]}]
    }));
    // Deterministic corruption: every byte of the header and JSON hit once, plus truncations.
    let mut rng = 0x2545_f491_4f6c_dd1du64;
    let mut next = || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        rng
    };
    for i in 0..glb.len() {
        let mut bad = glb.clone();
        bad[i] = (next() & 0xff) as u8;
        let _ = import_slice(&bad, None);
    }
    for len in 0..glb.len() {
        let _ = import_slice(&glb[..len], None);
    }
}

#[test]
fn a_node_cycle_is_reported_not_followed() {
    let mut g = Gltf::default();
    let pos = g.positions(&TRI);
    let doc = g.json(json!({
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "children": [1]}, {"children": [0]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": pos}}]}]
    }));
    let scene = import_json(&doc);
    assert_eq!(scene.triangles.len(), 1);
    let w = &scene.report.warnings;
    assert!(
        w.iter()
            .any(|w| w.contains("node #0") && w.contains("reached twice")),
        "{w:?}"
    );
}

#[test]
fn base64_test_helper_matches_known_strings() {
    assert_eq!(base64(b"hello!"), "aGVsbG8h");
    assert_eq!(base64(b"hello"), "aGVsbG8=");
}
