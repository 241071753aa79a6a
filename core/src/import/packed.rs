//! The check a packed model passes before a server hands it to browsers.
//!
//! A baked file's `MODL` section, or a `NAME.glb` beside `NAME.bounce`, comes from outside the
//! server: a file baked by an older bounce (which packed whatever a glTF's URIs named, absolute
//! paths and `../` included), or one written by hand. [`pack_glb`](super::pack_glb) makes models
//! that pass; this says whether some bytes are such a model: one GLB of at most
//! [`MAX_SERVED_MODEL_BYTES`] that parses and validates as glTF 2.0, names no URI (every buffer
//! and image is inside it, so nothing it makes a viewer fetch can reach anything else), has its
//! buffer views within its one BIN chunk, and whose images are the type they claim (PNG and
//! JPEG also decode), as at bake time.

use std::path::Path;

use thiserror::Error;

use super::pack::check_image;

/// The largest model a server keeps in memory and serves. Real scenes' models are tens of
/// megabytes; a GLB may be 4 GiB, which every scene would hold for the server's life.
pub const MAX_SERVED_MODEL_BYTES: u64 = 1 << 30;

/// Why bytes are not a model to serve.
#[derive(Debug, Error)]
#[error("not a servable model: {0}")]
pub struct PackedModelError(String);

impl PackedModelError {
    /// What is wrong, without the "not a servable model" prefix.
    pub fn reason(&self) -> &str {
        &self.0
    }
}

/// Checks `bytes` as the module doc says: `Ok` means a browser may be given them.
pub fn validate_packed(bytes: &[u8]) -> Result<(), PackedModelError> {
    let bad = |m: String| Err(PackedModelError(m));
    if bytes.len() as u64 > MAX_SERVED_MODEL_BYTES {
        return bad(format!(
            "{} bytes, over the limit of {MAX_SERVED_MODEL_BYTES}",
            bytes.len()
        ));
    }
    if !bytes.starts_with(b"glTF") {
        return bad("not a GLB (no 'glTF' magic): a packed model is one GLB".into());
    }
    let (container, root) =
        super::parse(bytes, Path::new("model")).map_err(|e| PackedModelError(e.to_string()))?;
    let bin = container.bin.unwrap_or(&[]);

    for (i, buffer) in root.buffers.iter().enumerate() {
        if let Some(uri) = &buffer.uri {
            return bad(format!(
                "buffer {i} names a URI ({}); a packed model holds its buffers",
                shorten(uri)
            ));
        }
        if i > 0 {
            return bad(format!(
                "buffer {i} has no URI; only buffer 0 can be the GLB's BIN chunk"
            ));
        }
        if buffer.byte_length.0 > bin.len() as u64 {
            return bad(format!(
                "buffer 0 claims {} bytes; the BIN chunk has {}",
                buffer.byte_length.0,
                bin.len()
            ));
        }
    }
    // Each view's bytes, within the BIN chunk (the only buffer left).
    let view_bytes = |v: usize| -> Result<&[u8], PackedModelError> {
        let view = root
            .buffer_views
            .get(v)
            .ok_or_else(|| PackedModelError(format!("buffer view {v} does not exist")))?;
        let start = view.byte_offset.map_or(0, |o| o.0);
        let end = start.checked_add(view.byte_length.0);
        match end {
            Some(end) if view.buffer.value() == 0 && end <= bin.len() as u64 => {
                // Both fit in the BIN chunk's length, a usize.
                Ok(&bin[start as usize..end as usize])
            }
            _ => Err(PackedModelError(format!(
                "buffer view {v} ({} bytes at {start} of buffer {}) is not within the BIN chunk \
                 ({} bytes)",
                view.byte_length.0,
                view.buffer.value(),
                bin.len()
            ))),
        }
    };
    for v in 0..root.buffer_views.len() {
        view_bytes(v)?;
    }

    for (i, image) in root.images.iter().enumerate() {
        if let Some(uri) = &image.uri {
            return bad(format!(
                "image {i} names a URI ({}); a packed model holds its images",
                shorten(uri)
            ));
        }
        let Some(view) = image.buffer_view else {
            return bad(format!("image {i} has neither a URI nor a buffer view"));
        };
        let Some(mime) = &image.mime_type else {
            return bad(format!("image {i} has no valid mimeType"));
        };
        let data = view_bytes(view.value())?;
        check_image(data, &mime.0).map_err(|e| PackedModelError(format!("image {i}: {e}")))?;
    }
    Ok(())
}

/// A URI as a log line shows it: a `data:` URI or a long name would fill the line.
fn shorten(uri: &str) -> String {
    let mut s: String = uri.chars().take(60).collect();
    if s.len() < uri.len() {
        s.push('…');
    }
    format!("'{s}'")
}

#[cfg(test)]
mod tests {
    use super::*;

    const PNG_1X1: &[u8] = &[
        0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x48, 0x44,
        0x52, 0x00, 0x00, 0x00, 0x01, 0x00, 0x00, 0x00, 0x01, 0x08, 0x02, 0x00, 0x00, 0x00, 0x90,
        0x77, 0x53, 0xde, 0x00, 0x00, 0x00, 0x0c, 0x49, 0x44, 0x41, 0x54, 0x78, 0x9c, 0x63, 0xf8,
        0xdf, 0xc0, 0x00, 0x00, 0x04, 0x01, 0x01, 0x80, 0xc5, 0x2a, 0x18, 0x5d, 0x00, 0x00, 0x00,
        0x00, 0x49, 0x45, 0x4e, 0x44, 0xae, 0x42, 0x60, 0x82,
    ];

    fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
        gltf::binary::Glb {
            header: gltf::binary::Header {
                magic: *b"glTF",
                version: 2,
                length: 0,
            },
            json: json.as_bytes().into(),
            bin: (!bin.is_empty()).then(|| bin.into()),
        }
        .to_vec()
        .unwrap()
    }

    fn image_model(mime: &str, image: &[u8]) -> Vec<u8> {
        let json = format!(
            r#"{{"asset":{{"version":"2.0"}},
            "buffers":[{{"byteLength":{n}}}],
            "bufferViews":[{{"buffer":0,"byteLength":{n}}}],
            "images":[{{"bufferView":0,"mimeType":"{mime}"}}]}}"#,
            n = image.len()
        );
        glb(&json, image)
    }

    #[test]
    fn a_packed_model_passes() {
        validate_packed(&image_model("image/png", PNG_1X1)).unwrap();
        validate_packed(&glb(r#"{"asset":{"version":"2.0"}}"#, &[])).unwrap();
    }

    #[test]
    fn what_a_hostile_or_old_bake_packed_is_refused() {
        let refused = |bytes: &[u8], why: &str| {
            let e = validate_packed(bytes).unwrap_err().to_string();
            assert!(e.contains(why), "{e}");
        };
        // What an older bake packed from `"uri": "/etc/passwd"` with a mimeType.
        refused(
            &image_model("image/png", b"root:x:0:0:root:/root:/bin/bash\n"),
            "image 0: its bytes are not a image/png image",
        );
        // PNG magic, then anything.
        let mut fake = PNG_1X1[..8].to_vec();
        fake.extend_from_slice(b"secret");
        refused(&image_model("image/png", &fake), "does not decode");
        refused(
            &glb(
                r#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":4,"uri":"../secret.bin"}]}"#,
                &[],
            ),
            "buffer 0 names a URI ('../secret.bin')",
        );
        refused(
            &glb(
                r#"{"asset":{"version":"2.0"},"images":[{"uri":"file:///etc/passwd"}]}"#,
                &[],
            ),
            "image 0 names a URI",
        );
        refused(
            &glb(
                r#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":64}],
                   "bufferViews":[{"buffer":0,"byteLength":64}]}"#,
                &[0; 8],
            ),
            "buffer 0 claims 64 bytes",
        );
        refused(br#"{"asset":{"version":"2.0"}}"#, "not a GLB");
        refused(b"glTF\x02\0\0\0\x04\0\0\0", "not a glTF 2.0 file");
    }
}
