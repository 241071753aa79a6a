//! Scenes written from the assets for what a test needs and no asset has.

use std::path::{Path, PathBuf};

/// The emissive Cornell box (`assets/cornell-box-emissive/CornellBox.glb`, its lamp the node
/// `Light` made of the material `Emitter_Light_temp`).
pub fn emissive_box() -> PathBuf {
    crate::assets().join("cornell-box-emissive/CornellBox.glb")
}

/// The emissive box with a second lamp: the `Light` node's mesh placed again by a node `Lamp 2`
/// (`TWO_LAMPS_DROP` units lower, in the box's own units), so two nodes share the lamp's
/// material. Written as `two-lamps.glb` in `dir`; its path.
pub fn two_lamps(dir: &Path) -> PathBuf {
    let glb = std::fs::read(emissive_box()).expect("the emissive box is in assets/");
    let json_len = u32::from_le_bytes(glb[12..16].try_into().expect("a GLB header")) as usize;
    let mut json: serde_json::Value =
        serde_json::from_slice(&glb[20..20 + json_len]).expect("the GLB's JSON chunk");
    let bin = &glb[20 + json_len..];
    let light = json["nodes"][0].clone();
    assert_eq!(light["name"], "Light", "the box's first node is its lamp");
    let at = |i: usize| {
        light["translation"]
            .get(i)
            .and_then(serde_json::Value::as_f64)
            .unwrap_or(0.0)
    };
    let mut second = light.clone();
    second["name"] = "Lamp 2".into();
    second["translation"] = serde_json::json!([at(0), at(1) - TWO_LAMPS_DROP, at(2)]);
    let nodes = json["nodes"].as_array_mut().expect("nodes");
    nodes.push(second);
    let index = nodes.len() - 1;
    let scene = json["scene"].as_u64().unwrap_or(0) as usize;
    json["scenes"][scene]["nodes"]
        .as_array_mut()
        .expect("the scene's nodes")
        .push(index.into());
    let mut text = serde_json::to_vec(&json).expect("JSON");
    text.resize(text.len().next_multiple_of(4), b' ');
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&((12 + 8 + text.len() + bin.len()) as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    out.extend_from_slice(bin);
    std::fs::create_dir_all(dir).expect("the scene's directory");
    let path = dir.join("two-lamps.glb");
    std::fs::write(&path, out).expect("writing the scene");
    path
}

/// How far below the first lamp [`two_lamps`] puts the second.
pub const TWO_LAMPS_DROP: f64 = 100.0;
