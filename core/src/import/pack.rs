//! One self-contained GLB from a glTF asset: what a baked file keeps of its scene so that a
//! browser can draw it without the files it was baked from.
//!
//! Every buffer (external `.bin`, `data:` URI, or a GLB's own BIN chunk) goes into the one BIN
//! chunk, each starting 4-byte aligned, and every image with a `uri` becomes a buffer view with
//! its `mimeType`. The JSON is edited as a `serde_json::Value` rather than through
//! `gltf::json::Root`: the typed root drops what its enabled features do not model (unknown
//! extensions such as `KHR_texture_transform` or `KHR_materials_*`, unknown fields) and rounds
//! numbers through `f32`. Editing the value touches only `buffers`, `bufferViews` and `images`;
//! materials, extensions and extras stay as they were, numbers included (serde_json's
//! `float_roundtrip`).

use std::path::{Path, PathBuf};

use serde_json::{Map, Value, json};
use thiserror::Error;

use super::source;

/// What can stop a scene from being packed. Messages name the scene file and, for a resource,
/// the buffer or image and the file it points to.
#[derive(Debug, Error)]
pub enum PackError {
    // The cause is in the message, not a `source`, so a reporter printing the chain does not
    // repeat it.
    #[error("{}: {error}", path.display())]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("{}: not a glTF 2.0 file: {reason}", path.display())]
    NotGltf { path: PathBuf, reason: String },
    #[error("{}: {what} cannot be read: {reason} (keep the files a .gltf names beside it)", path.display())]
    Resource {
        path: PathBuf,
        /// `buffer 0 ('scene.bin')`, `image 3 ('wood.png')`.
        what: String,
        reason: String,
    },
    #[error("{}: the packed model would be {bytes} bytes, over the GLB limit of 4 GiB", path.display())]
    TooLarge { path: PathBuf, bytes: u64 },
    /// The result fails the check a server makes before serving a model
    /// ([`validate_packed`](super::validate_packed)): an embedded image that is not what it
    /// claims, an image with no data, a view past its buffer.
    #[error("{}: the packed model would not be served: {reason}", path.display())]
    Unservable { path: PathBuf, reason: String },
}

/// Alignment of each buffer and image in the BIN chunk: the largest glTF component size.
const ALIGN: usize = 4;

/// The scene at `path` (`.gltf` or `.glb`) as one self-contained GLB. A GLB whose buffers and
/// images name no URI is returned as it is.
pub fn pack_glb(path: &Path) -> Result<Vec<u8>, PackError> {
    let bytes = std::fs::read(path).map_err(|error| PackError::Io {
        path: path.to_path_buf(),
        error,
    })?;
    pack_bytes(&bytes, Some(super::base_dir(path)), path)
}

/// As [`pack_glb`], from the file's bytes; external files are resolved relative to `base`.
/// `path` names the scene in errors. What it returns passes
/// [`validate_packed`](super::validate_packed), so a server serves every model a bake keeps.
pub fn pack_bytes(bytes: &[u8], base: Option<&Path>, path: &Path) -> Result<Vec<u8>, PackError> {
    let glb = pack_unchecked(bytes, base, path)?;
    super::validate_packed(&glb).map_err(|e| PackError::Unservable {
        path: path.to_path_buf(),
        reason: e.reason().to_string(),
    })?;
    Ok(glb)
}

fn pack_unchecked(bytes: &[u8], base: Option<&Path>, path: &Path) -> Result<Vec<u8>, PackError> {
    let not_gltf = |reason: String| PackError::NotGltf {
        path: path.to_path_buf(),
        reason,
    };
    let container = source::split(bytes).map_err(not_gltf)?;
    let mut root: Value = serde_json::from_slice(container.json)
        .map_err(|e| not_gltf(format!("invalid JSON: {e}")))?;
    let Some(doc) = root.as_object_mut() else {
        return Err(not_gltf("the JSON is not an object".into()));
    };
    let is_glb = bytes.starts_with(b"glTF");
    let names_uri = |key: &str| {
        doc.get(key)
            .and_then(Value::as_array)
            .is_some_and(|a| a.iter().any(|e| e.get("uri").is_some()))
    };
    if is_glb && !names_uri("buffers") && !names_uri("images") {
        return Ok(bytes.to_vec());
    }

    let resource = |what: String, reason: String| PackError::Resource {
        path: path.to_path_buf(),
        what,
        reason,
    };
    let mut bin: Vec<u8> = Vec::new();
    let append = |bin: &mut Vec<u8>, data: &[u8]| {
        bin.resize(bin.len().next_multiple_of(ALIGN), 0);
        let at = bin.len();
        bin.extend_from_slice(data);
        at
    };

    // Buffers: each placed in the new BIN chunk, remembering where.
    let buffers = array(doc, "buffers").map_err(not_gltf)?;
    let mut placed = Vec::with_capacity(buffers.len());
    for (i, b) in buffers.iter().enumerate() {
        let uri = b.get("uri").and_then(Value::as_str);
        let what = || match uri {
            Some(u) if !u.starts_with("data:") => format!("buffer {i} ('{u}')"),
            _ => format!("buffer {i}"),
        };
        let len = b
            .get("byteLength")
            .and_then(Value::as_u64)
            .ok_or_else(|| not_gltf(format!("buffer {i} has no byteLength")))?;
        let data = match uri {
            Some(u) => source::read_uri(u, base).map_err(|e| resource(what(), e))?,
            // A buffer without a URI is the GLB's own BIN chunk, and only the first may be.
            None if i == 0 => container
                .bin
                .map(<[u8]>::to_vec)
                .ok_or_else(|| resource(what(), "no URI and no GLB BIN chunk".into()))?,
            None => {
                return Err(resource(
                    what(),
                    "no URI (only buffer 0 of a GLB may have none)".into(),
                ));
            }
        };
        let data = usize::try_from(len)
            .ok()
            .and_then(|n| data.get(..n))
            .ok_or_else(|| {
                resource(
                    what(),
                    format!("{} bytes, but byteLength says {len}", data.len()),
                )
            })?;
        placed.push((append(&mut bin, data), data.len() as u64));
    }

    // Buffer views: all into buffer 0, shifted by where their buffer went.
    let mut views = array(doc, "bufferViews").map_err(not_gltf)?;
    for (i, v) in views.iter_mut().enumerate() {
        let obj = v
            .as_object_mut()
            .ok_or_else(|| not_gltf(format!("buffer view {i} is not an object")))?;
        let (at, buffer_len) = obj
            .get("buffer")
            .and_then(Value::as_u64)
            .and_then(|b| placed.get(usize::try_from(b).ok()?))
            .copied()
            .ok_or_else(|| not_gltf(format!("buffer view {i} names no existing buffer")))?;
        let offset = obj.get("byteOffset").and_then(Value::as_u64).unwrap_or(0);
        // Once every buffer is one, a view past the end of its own would read the next buffer's
        // bytes (or past the BIN chunk, which the server refuses to serve).
        let length = obj.get("byteLength").and_then(Value::as_u64);
        match length.and_then(|n| offset.checked_add(n)) {
            Some(end) if end <= buffer_len => {}
            _ => {
                return Err(not_gltf(format!(
                    "buffer view {i} ({} bytes at {offset}) is not within its buffer ({buffer_len} \
                     bytes)",
                    length.map_or("no byteLength".to_string(), |n| n.to_string())
                )));
            }
        }
        obj.insert("buffer".into(), json!(0));
        obj.insert("byteOffset".into(), json!(offset + at as u64));
    }

    // Images with a URI: their bytes appended, each behind a new buffer view.
    let mut images = array(doc, "images").map_err(not_gltf)?;
    for (i, image) in images.iter_mut().enumerate() {
        let obj = image
            .as_object_mut()
            .ok_or_else(|| not_gltf(format!("image {i} is not an object")))?;
        let Some(uri) = obj.get("uri").and_then(Value::as_str).map(str::to_owned) else {
            continue;
        };
        let what = if uri.starts_with("data:") {
            format!("image {i}")
        } else {
            format!("image {i} ('{uri}')")
        };
        let data = source::read_uri(&uri, base).map_err(|e| resource(what.clone(), e))?;
        let mime = mime_of(&uri)
            .map(str::to_owned)
            .or_else(|| {
                obj.get("mimeType")
                    .and_then(Value::as_str)
                    .map(str::to_owned)
            })
            .or_else(|| sniff_mime(&data).map(str::to_owned))
            .ok_or_else(|| {
                resource(
                    what.clone(),
                    "unknown image type (not png, jpeg, webp or ktx2; give it a mimeType)".into(),
                )
            })?;
        check_image(&data, &mime).map_err(|e| resource(what, e))?;
        let at = append(&mut bin, &data);
        obj.remove("uri");
        obj.insert("bufferView".into(), json!(views.len()));
        obj.insert("mimeType".into(), json!(mime));
        views.push(json!({
            "buffer": 0,
            "byteOffset": at,
            "byteLength": data.len(),
        }));
    }

    let total = bin.len();
    if total as u64 > u64::from(u32::MAX) - 1024 {
        return Err(PackError::TooLarge {
            path: path.to_path_buf(),
            bytes: total as u64,
        });
    }
    // The first buffer keeps its name and extras; only its URI and length change.
    let mut buffer = buffers
        .into_iter()
        .next()
        .and_then(|b| match b {
            Value::Object(m) => Some(m),
            _ => None,
        })
        .unwrap_or_default();
    buffer.remove("uri");
    buffer.insert("byteLength".into(), json!(total));
    put(
        doc,
        "buffers",
        (total > 0 || !placed.is_empty()).then(|| vec![Value::Object(buffer)]),
    );
    put(doc, "bufferViews", (!views.is_empty()).then_some(views));
    put(doc, "images", (!images.is_empty()).then_some(images));

    let json = serde_json::to_vec(&root).map_err(|e| not_gltf(format!("re-encoding: {e}")))?;
    let has_bin = total > 0 || !placed.is_empty();
    let glb = gltf::binary::Glb {
        header: gltf::binary::Header {
            magic: *b"glTF",
            version: 2,
            // Computed by the writer.
            length: 0,
        },
        json: json.into(),
        bin: has_bin.then(|| bin.into()),
    };
    glb.to_vec().map_err(|e| PackError::NotGltf {
        path: path.to_path_buf(),
        reason: format!("writing the GLB: {e}"),
    })
}

/// The array at `key`, taken out of `doc` (empty when absent).
fn array(doc: &mut Map<String, Value>, key: &str) -> Result<Vec<Value>, String> {
    match doc.remove(key) {
        None => Ok(Vec::new()),
        Some(Value::Array(a)) => Ok(a),
        Some(_) => Err(format!("'{key}' is not an array")),
    }
}

fn put(doc: &mut Map<String, Value>, key: &str, value: Option<Vec<Value>>) {
    if let Some(v) = value {
        doc.insert(key.into(), Value::Array(v));
    }
}

/// The MIME type a URI states: a `data:` URI's, else by the file's extension.
fn mime_of(uri: &str) -> Option<&'static str> {
    let known = |s: &str| -> Option<&'static str> {
        Some(match s.to_ascii_lowercase().as_str() {
            "image/png" | "png" => "image/png",
            "image/jpeg" | "image/jpg" | "jpg" | "jpeg" => "image/jpeg",
            "image/webp" | "webp" => "image/webp",
            "image/ktx2" | "ktx2" => "image/ktx2",
            _ => return None,
        })
    };
    if let Some(rest) = uri.strip_prefix("data:") {
        let header = rest.split_once(',')?.0;
        return known(header.split(';').next()?);
    }
    let path = uri.split(['?', '#']).next()?;
    known(path.rsplit_once('.')?.1)
}

/// The type an image's bytes announce, for a URI that says nothing.
/// The packed model is served to browsers: an image goes in only if its bytes are the type it
/// claims, and PNG and JPEG (the types bounce decodes) only if they decode.
pub(super) fn check_image(data: &[u8], mime: &str) -> Result<(), String> {
    match sniff_mime(data) {
        Some(found) if found == mime => {}
        Some(found) => return Err(format!("its bytes are {found}, not {mime}")),
        None => return Err(format!("its bytes are not a {mime} image")),
    }
    if matches!(mime, "image/png" | "image/jpeg") {
        image::load_from_memory(data).map_err(|e| format!("it does not decode as {mime}: {e}"))?;
    }
    Ok(())
}

fn sniff_mime(data: &[u8]) -> Option<&'static str> {
    if data.starts_with(b"\x89PNG") {
        Some("image/png")
    } else if data.starts_with(&[0xFF, 0xD8, 0xFF]) {
        Some("image/jpeg")
    } else if data.len() >= 12 && &data[..4] == b"RIFF" && &data[8..12] == b"WEBP" {
        Some("image/webp")
    } else if data.starts_with(b"\xABKTX 20") {
        Some("image/ktx2")
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mime_types_come_from_data_uris_then_extensions() {
        assert_eq!(mime_of("data:image/png;base64,AAAA"), Some("image/png"));
        assert_eq!(mime_of("data:image/jpeg;base64,AAAA"), Some("image/jpeg"));
        assert_eq!(mime_of("tex/Wood.JPG"), Some("image/jpeg"));
        assert_eq!(mime_of("a.webp?x=1"), Some("image/webp"));
        assert_eq!(mime_of("a.ktx2"), Some("image/ktx2"));
        assert_eq!(mime_of("a.bmp"), None);
        assert_eq!(mime_of("data:application/octet-stream;base64,AA"), None);
    }

    /// Found by the `gltf_import` fuzz target: a view past the end of its buffer was packed, into
    /// a model that reads the next buffer's bytes or that the server refuses to serve.
    #[test]
    fn a_view_past_its_buffer_is_refused() {
        let gltf = |offset: u64, length: u64| {
            format!(
                r#"{{"asset":{{"version":"2.0"}},
                "buffers":[{{"byteLength":4,"uri":"data:,abcd"}},{{"byteLength":4,"uri":"data:,efgh"}}],
                "bufferViews":[{{"buffer":0,"byteOffset":{offset},"byteLength":{length}}}]}}"#
            )
        };
        let path = Path::new("view.gltf");
        pack_bytes(gltf(0, 4).as_bytes(), None, path).unwrap();
        pack_bytes(gltf(2, 2).as_bytes(), None, path).unwrap();
        for (offset, length) in [(0, 5), (4, 1), (u64::MAX, 2)] {
            let e = pack_bytes(gltf(offset, length).as_bytes(), None, path).unwrap_err();
            assert!(
                e.to_string().contains("buffer view 0") && e.to_string().contains("not within"),
                "{e}"
            );
        }
    }

    #[test]
    fn image_bytes_announce_their_type() {
        assert_eq!(sniff_mime(b"\x89PNG\r\n"), Some("image/png"));
        assert_eq!(sniff_mime(&[0xFF, 0xD8, 0xFF, 0xE0]), Some("image/jpeg"));
        assert_eq!(sniff_mime(b"GIF89a"), None);
    }
}
