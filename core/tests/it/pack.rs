//! `pack_glb`: a glTF with external files or data URIs, a GLB, and the repository's real scenes
//! become one self-contained GLB that reads back with the same meshes, materials and images.

use std::path::{Path, PathBuf};

use bounce_core::import::{PackError, import_path, pack_glb};
use serde_json::{Value, json};

/// A one-triangle mesh with a base-colour texture, its buffer and image named by `buffer_uri`
/// and `image_uri`; extensions and extras that must survive packing untouched.
fn triangle_gltf(buffer_uri: &str, buffer_len: usize, image_uri: &str) -> Value {
    json!({
        "asset": {"version": "2.0", "generator": "bounce pack test"},
        "extensionsUsed": ["KHR_texture_transform", "KHR_materials_emissive_strength", "KHR_lights_punctual"],
        "extensions": {"KHR_lights_punctual": {"lights": [{"type": "point", "intensity": 3.5, "color": [1.0, 0.5, 0.25]}]}},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [
            {"mesh": 0, "extras": {"note": "kept"}},
            {"translation": [0.0, 2.0, 0.0], "extensions": {"KHR_lights_punctual": {"light": 0}}}
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "material": 0}]}],
        "materials": [{
            "name": "textured",
            "pbrMetallicRoughness": {
                "baseColorFactor": [0.9, 0.8, 0.7, 1.0],
                "baseColorTexture": {"index": 0, "extensions": {"KHR_texture_transform": {"scale": [2.0, 3.0], "rotation": 0.1}}}
            },
            "emissiveFactor": [0.1, 0.2, 0.30000000000000004],
            "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 4.0}},
            "extras": {"anything": [1, 2, 3]}
        }],
        "textures": [{"source": 0}],
        "images": [{"uri": image_uri}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
             "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0]},
            {"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC2"}
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 36},
            {"buffer": 0, "byteOffset": 36, "byteLength": 24}
        ],
        "buffers": [{"uri": buffer_uri, "byteLength": buffer_len}]
    })
}

fn triangle_bin() -> Vec<u8> {
    let floats: [f32; 15] = [
        0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, // positions
        0.0, 0.0, 1.0, 0.0, 0.0, 1.0, // uvs
    ];
    floats.iter().flat_map(|f| f.to_le_bytes()).collect()
}

fn png_bytes() -> Vec<u8> {
    let img = image::RgbaImage::from_fn(4, 2, |x, y| {
        image::Rgba([x as u8 * 60, y as u8 * 100, 7, 255])
    });
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

fn base64(bytes: &[u8]) -> String {
    const T: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in bytes.chunks(3) {
        let n = (u32::from(c[0]) << 16)
            | (u32::from(*c.get(1).unwrap_or(&0)) << 8)
            | u32::from(*c.get(2).unwrap_or(&0));
        for i in 0..4 {
            if i <= c.len() {
                s.push(T[(n >> (18 - 6 * i) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

fn unbase64(s: &str) -> Vec<u8> {
    let value = |c: u8| match c {
        b'A'..=b'Z' => c - b'A',
        b'a'..=b'z' => c - b'a' + 26,
        b'0'..=b'9' => c - b'0' + 52,
        b'+' => 62,
        _ => 63,
    };
    let (mut out, mut acc, mut bits) = (Vec::new(), 0u32, 0);
    for c in s.bytes().filter(|&c| c != b'=') {
        acc = (acc << 6) | u32::from(value(c));
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
        }
    }
    out
}

/// The packed GLB's JSON and BIN chunk.
fn chunks(glb: &[u8]) -> (Value, Vec<u8>) {
    let g = gltf::Glb::from_slice(glb).expect("a GLB");
    let json = serde_json::from_slice(&g.json).expect("JSON chunk");
    (json, g.bin.map(|b| b.into_owned()).unwrap_or_default())
}

/// Every image's bytes, as the packed file stores them.
fn image_bytes(json: &Value, bin: &[u8]) -> Vec<Vec<u8>> {
    let views = json["bufferViews"].as_array().unwrap();
    json["images"]
        .as_array()
        .map(|a| a.as_slice())
        .unwrap_or_default()
        .iter()
        .map(|im| {
            assert!(im.get("uri").is_none(), "image still has a uri: {im}");
            assert!(im["mimeType"].is_string(), "image without mimeType: {im}");
            let v = &views[im["bufferView"].as_u64().unwrap() as usize];
            let at = v["byteOffset"].as_u64().unwrap_or(0) as usize;
            let len = v["byteLength"].as_u64().unwrap() as usize;
            bin[at..at + len].to_vec()
        })
        .collect()
}

/// Meshes, primitives per mesh and vertices per primitive, as gltf's own importer reads them.
fn shape(doc: &gltf::Document) -> Vec<Vec<usize>> {
    doc.meshes()
        .map(|m| {
            m.primitives()
                .map(|p| p.get(&gltf::Semantic::Positions).map_or(0, |a| a.count()))
                .collect()
        })
        .collect()
}

/// The packed file reads back with gltf's importer (no files around it) as the original does,
/// and holds the same JSON and bytes.
fn assert_same_scene(original: &Path, glb: &[u8]) {
    let (doc_a, buffers_a, images_a) = gltf::import(original).expect("original imports");
    let (doc_b, buffers_b, images_b) = gltf::import_slice(glb).expect("packed GLB imports");
    assert_eq!(shape(&doc_a), shape(&doc_b), "{}", original.display());
    assert_eq!(buffers_b.len(), usize::from(!buffers_a.is_empty()));
    assert_eq!(images_a.len(), images_b.len());
    for (a, b) in images_a.iter().zip(&images_b) {
        assert_eq!(
            (a.width, a.height, &a.pixels),
            (b.width, b.height, &b.pixels)
        );
    }
    assert_same_json_and_bytes(original, glb);
}

/// The packed file's JSON is the source's but for buffers, views and images; every view holds
/// the bytes it held; every image with a URI holds that file's bytes. Needs no glTF importer,
/// so it also covers files whose required extensions the `gltf` crate refuses.
fn assert_same_json_and_bytes(original: &Path, glb: &[u8]) {
    let base = original.parent().unwrap();
    let source = std::fs::read(original).unwrap();
    let (json_a, bin_a) = if source.starts_with(b"glTF") {
        chunks(&source)
    } else {
        (serde_json::from_slice(&source).unwrap(), Vec::new())
    };
    let (json_b, bin_b) = chunks(glb);
    let buffer_a = |i: usize| -> Vec<u8> {
        match json_a["buffers"][i]["uri"].as_str() {
            Some(uri) => match uri.split_once(";base64,") {
                Some((_, data)) => unbase64(data),
                None => std::fs::read(base.join(uri.replace("%20", " "))).unwrap(),
            },
            None => bin_a.clone(),
        }
    };
    let view = |v: &Value, bytes: &[u8]| -> Vec<u8> {
        let at = v["byteOffset"].as_u64().unwrap_or(0) as usize;
        bytes[at..at + v["byteLength"].as_u64().unwrap() as usize].to_vec()
    };
    let views_a = json_a["bufferViews"]
        .as_array()
        .cloned()
        .unwrap_or_default();
    for (i, va) in views_a.iter().enumerate() {
        let vb = &json_b["bufferViews"][i];
        let a = view(va, &buffer_a(va["buffer"].as_u64().unwrap() as usize));
        assert_eq!(
            a,
            view(vb, &bin_b),
            "{}: buffer view {i}",
            original.display()
        );
        for key in ["byteStride", "target", "name"] {
            assert_eq!(
                va.get(key),
                vb.get(key),
                "{}: view {i} {key}",
                original.display()
            );
        }
    }
    let images_a = json_a["images"].as_array().cloned().unwrap_or_default();
    let packed = image_bytes(&json_b, &bin_b);
    for (i, im) in images_a.iter().enumerate() {
        if let Some(uri) = im["uri"].as_str().filter(|u| !u.starts_with("data:")) {
            let want = std::fs::read(base.join(uri)).unwrap();
            assert!(
                want == packed[i],
                "{}: image {i} ('{uri}')",
                original.display()
            );
        }
        if let Some(name) = im.get("name") {
            assert_eq!(Some(name), json_b["images"][i].get("name"));
        }
    }
    // Everything but buffers, views and images is the JSON the source had.
    for (key, value) in json_a.as_object().unwrap() {
        if !["buffers", "bufferViews", "images"].contains(&key.as_str()) {
            assert_eq!(
                Some(value),
                json_b.get(key),
                "{}: '{key}' changed",
                original.display()
            );
        }
    }
}

#[test]
fn external_bin_and_png_are_packed_into_one_glb() {
    let dir = tempfile::tempdir().unwrap();
    let bin = triangle_bin();
    let png = png_bytes();
    std::fs::create_dir(dir.path().join("tex")).unwrap();
    std::fs::write(dir.path().join("tri angle.bin"), &bin).unwrap();
    std::fs::write(dir.path().join("tex/wood.png"), &png).unwrap();
    let gltf_path = dir.path().join("scene.gltf");
    let doc = triangle_gltf("tri%20angle.bin", bin.len(), "tex/wood.png");
    std::fs::write(&gltf_path, serde_json::to_vec_pretty(&doc).unwrap()).unwrap();

    let glb = pack_glb(&gltf_path).expect("packs");
    let (json, chunk) = chunks(&glb);
    assert_eq!(json["buffers"].as_array().unwrap().len(), 1);
    assert!(json["buffers"][0].get("uri").is_none());
    assert_eq!(image_bytes(&json, &chunk), vec![png.clone()]);
    assert_eq!(json["images"][0]["mimeType"], "image/png");
    assert_eq!(
        json["materials"], doc["materials"],
        "materials kept exactly"
    );
    assert_eq!(json["extensions"], doc["extensions"]);
    assert_eq!(json["nodes"], doc["nodes"]);
    assert_same_scene(&gltf_path, &glb);

    // Alone in another directory, with nothing beside it, it still reads.
    let lone = tempfile::tempdir().unwrap();
    let moved = lone.path().join("moved.glb");
    std::fs::write(&moved, &glb).unwrap();
    assert!(gltf::import(&moved).is_ok());
    // And packing a self-contained GLB again changes nothing.
    assert_eq!(pack_glb(&moved).unwrap(), glb);
}

#[test]
fn data_uris_are_decoded_and_typed() {
    let dir = tempfile::tempdir().unwrap();
    let bin = triangle_bin();
    let png = png_bytes();
    let doc = triangle_gltf(
        &format!("data:application/octet-stream;base64,{}", base64(&bin)),
        bin.len(),
        &format!("data:image/png;base64,{}", base64(&png)),
    );
    let gltf_path = dir.path().join("inline.gltf");
    std::fs::write(&gltf_path, serde_json::to_vec(&doc).unwrap()).unwrap();
    let glb = pack_glb(&gltf_path).expect("packs");
    let (json, chunk) = chunks(&glb);
    assert_eq!(image_bytes(&json, &chunk), vec![png]);
    assert_eq!(json["images"][0]["mimeType"], "image/png");
    assert_same_scene(&gltf_path, &glb);
}

#[test]
fn a_missing_file_or_bad_json_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let bin = triangle_bin();
    std::fs::write(dir.path().join("tri.bin"), &bin).unwrap();
    let gltf_path = dir.path().join("scene.gltf");
    let doc = triangle_gltf("tri.bin", bin.len(), "missing-texture.png");
    std::fs::write(&gltf_path, serde_json::to_vec(&doc).unwrap()).unwrap();
    let e = pack_glb(&gltf_path).unwrap_err();
    assert!(matches!(e, PackError::Resource { .. }), "{e:?}");
    let msg = e.to_string();
    assert!(
        msg.contains("scene.gltf") && msg.contains("image 0 ('missing-texture.png')"),
        "{msg}"
    );
    assert!(
        msg.contains("missing-texture.png:"),
        "names the file it looked for: {msg}"
    );

    let doc = triangle_gltf("gone.bin", bin.len(), "x.png");
    std::fs::write(&gltf_path, serde_json::to_vec(&doc).unwrap()).unwrap();
    let msg = pack_glb(&gltf_path).unwrap_err().to_string();
    assert!(msg.contains("buffer 0 ('gone.bin')"), "{msg}");

    // A buffer shorter than it claims.
    let doc = triangle_gltf("tri.bin", bin.len() + 4, "x.png");
    std::fs::write(&gltf_path, serde_json::to_vec(&doc).unwrap()).unwrap();
    let msg = pack_glb(&gltf_path).unwrap_err().to_string();
    assert!(msg.contains("byteLength"), "{msg}");

    std::fs::write(&gltf_path, b"{ not json").unwrap();
    let msg = pack_glb(&gltf_path).unwrap_err().to_string();
    assert!(
        msg.contains("scene.gltf") && msg.contains("invalid JSON"),
        "{msg}"
    );

    let msg = pack_glb(&dir.path().join("nowhere.gltf"))
        .unwrap_err()
        .to_string();
    assert!(msg.contains("nowhere.gltf"), "{msg}");
}

/// A glTF is input from outside and its packed model is served to anyone: its URIs cannot pack
/// a file from outside its directory, and an image must be what it claims and decode.
#[test]
fn a_hostile_gltf_packs_nothing_from_outside_and_no_broken_images() {
    let outer = tempfile::tempdir().unwrap();
    let dir = outer.path().join("scene");
    std::fs::create_dir(&dir).unwrap();
    let bin = triangle_bin();
    std::fs::write(dir.join("tri.bin"), &bin).unwrap();
    std::fs::write(outer.path().join("secret.png"), png_bytes()).unwrap();
    std::fs::write(dir.join("notes.png"), b"not an image at all").unwrap();
    let mut broken = png_bytes();
    broken.truncate(24);
    std::fs::write(dir.join("broken.png"), &broken).unwrap();
    std::fs::write(dir.join("real.jpg"), png_bytes()).unwrap();
    let gltf_path = dir.join("scene.gltf");
    for (image, why) in [
        ("../secret.png", "outside the glTF's directory"),
        ("/etc/hostname", "absolute path"),
        ("file:///etc/hostname", "scheme 'file:' refused"),
        ("notes.png", "not a image/png image"),
        ("broken.png", "does not decode as image/png"),
        ("real.jpg", "its bytes are image/png, not image/jpeg"),
    ] {
        let doc = triangle_gltf("tri.bin", bin.len(), image);
        std::fs::write(&gltf_path, serde_json::to_vec(&doc).unwrap()).unwrap();
        let msg = pack_glb(&gltf_path).unwrap_err().to_string();
        assert!(msg.contains(why), "{image}: {msg}");
    }
    // A buffer outside is refused the same way.
    std::fs::write(outer.path().join("outside.bin"), &bin).unwrap();
    let doc = triangle_gltf("../outside.bin", bin.len(), "x.png");
    std::fs::write(&gltf_path, serde_json::to_vec(&doc).unwrap()).unwrap();
    let msg = pack_glb(&gltf_path).unwrap_err().to_string();
    assert!(msg.contains("outside the glTF's directory"), "{msg}");
}

fn repo_scene(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

#[test]
fn the_repositorys_scenes_pack() {
    // The embedded demo: a .gltf with an external .bin.
    let cornell = repo_scene("../assets/cornell-box/scene.gltf");
    let glb = pack_glb(&cornell).expect("Cornell box packs");
    assert_same_scene(&cornell, &glb);

    // A .gltf with external JPEG textures and KHR_* material extensions.
    let chair = repo_scene("../assets/sheen-chair-sun/MixedLightingExample.gltf");
    let glb = pack_glb(&chair).expect("sheen chair packs");
    let (json, chunk) = chunks(&glb);
    let images = image_bytes(&json, &chunk);
    assert!(!images.is_empty());
    assert!(
        json["images"]
            .as_array()
            .unwrap()
            .iter()
            .all(|i| i["mimeType"] == "image/jpeg")
    );
    // It requires KHR_texture_transform, which the `gltf` crate as built here refuses: compare
    // bytes and JSON, and import both with bounce's own importer.
    assert_same_json_and_bytes(&chair, &glb);
    let dir = tempfile::tempdir().unwrap();
    let packed = dir.path().join("chair.glb");
    std::fs::write(&packed, &glb).unwrap();
    let (a, b) = (import_path(&chair).unwrap(), import_path(&packed).unwrap());
    assert_eq!(a.report, b.report);
    assert_eq!(a.lights, b.lights);

    // A GLB that is self-contained already passes through unchanged.
    let room = repo_scene("../assets/room-with-objects/room.glb");
    assert_eq!(pack_glb(&room).unwrap(), std::fs::read(&room).unwrap());

    // Every other scene packs too: packing now also runs the check a server makes before it
    // serves a model (`validate_packed`), which a self-contained GLB must pass as it is.
    for scene in [
        "../assets/pandora/pandora.glb",
        "../assets/small-room/IrradianceVolumeExample.glb",
        "../assets/cornell-box-emissive/CornellBox.glb",
    ] {
        let path = repo_scene(scene);
        let glb = pack_glb(&path).unwrap_or_else(|e| panic!("{scene}: {e}"));
        bounce_core::import::validate_packed(&glb).unwrap();
    }
}
