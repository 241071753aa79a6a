//! Raw bytes of a glTF asset: the GLB container, and the buffers and images its URIs name.
//!
//! Done here rather than by `gltf::import`, which fails the whole import on one missing image and
//! panics on some malformed input (a GLB length field below the header size, a relative URI whose
//! percent-escapes are not UTF-8).

use std::path::Path;

/// The JSON chunk and the optional BIN chunk of a GLB file, or the whole input for `.gltf`.
pub(crate) struct Container<'a> {
    pub json: &'a [u8],
    pub bin: Option<&'a [u8]>,
}

const GLB_MAGIC: &[u8; 4] = b"glTF";
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;

/// Splits a GLB file into its chunks; anything not starting with the GLB magic is taken as JSON.
pub(crate) fn split(bytes: &[u8]) -> Result<Container<'_>, String> {
    if !bytes.starts_with(GLB_MAGIC) {
        return Ok(Container {
            json: bytes,
            bin: None,
        });
    }
    let word = |at: usize| -> Option<u32> {
        let b = bytes.get(at..at + 4)?;
        Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let version = word(4).ok_or("GLB header truncated")?;
    if version != 2 {
        return Err(format!("GLB version {version}, expected 2"));
    }
    let length = word(8).ok_or("GLB header truncated")? as usize;
    if length < 12 || length > bytes.len() {
        return Err(format!(
            "GLB header says {length} bytes, file has {}",
            bytes.len()
        ));
    }
    let mut at = 12;
    let mut json = None;
    let mut bin = None;
    while at + 8 <= length {
        let chunk_len = word(at).ok_or("GLB chunk header truncated")? as usize;
        let chunk_type = word(at + 4).ok_or("GLB chunk header truncated")?;
        let start = at + 8;
        let data = start
            .checked_add(chunk_len)
            .filter(|&end| end <= length)
            .and_then(|end| bytes.get(start..end))
            .ok_or_else(|| format!("GLB chunk at byte {at} ({chunk_len} bytes) is truncated"))?;
        match chunk_type {
            CHUNK_JSON if json.is_none() && at == 12 => json = Some(data),
            CHUNK_BIN if bin.is_none() && json.is_some() => bin = Some(data),
            // The spec tells readers to skip chunk types they do not know.
            _ if at == 12 => return Err("GLB does not start with a JSON chunk".into()),
            _ => {}
        }
        at = start + chunk_len;
    }
    let mut json = json.ok_or("GLB has no JSON chunk")?;
    // Some writers pad the JSON chunk with NULs instead of spaces, which a JSON parser rejects.
    while let [rest @ .., 0] = json {
        json = rest;
    }
    Ok(Container { json, bin })
}

/// The most bytes one buffer or image file may hold: a GLB's whole length field is a u32, and
/// no scene bounce can bake needs more. A device file (`/dev/zero`) or a file that grows while it
/// is read stops here rather than at the end of memory.
pub(crate) const MAX_RESOURCE_BYTES: u64 = 1 << 31;

/// Reads what a URI names: a `data:` URI, or a file beneath `base`, the glTF's own directory.
///
/// A glTF is input from outside, and what its URIs name ends up in the baked file's model, which
/// the server hands to any browser. So a URI may not reach the rest of the machine: absolute
/// paths, `file:` and every other scheme are refused, a relative path must resolve (after `..`
/// and symbolic links) beneath `base`, and it must name a regular file of at most
/// [`MAX_RESOURCE_BYTES`].
pub(crate) fn read_uri(uri: &str, base: Option<&Path>) -> Result<Vec<u8>, String> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (header, payload) = rest.split_once(',').ok_or("data URI without a comma")?;
        return if header.ends_with(";base64") {
            base64(payload)
        } else {
            Ok(percent_decode(payload))
        };
    }
    if let Some(s) = scheme(uri) {
        return Err(format!(
            "URI scheme '{s}:' refused: a glTF's buffers and images must be data: URIs or files \
             beneath its own directory"
        ));
    }
    let base = base
        .ok_or_else(|| format!("'{uri}' is an external file, but no base directory was given"))?;
    let relative = String::from_utf8_lossy(&percent_decode(uri)).into_owned();
    let relative = Path::new(&relative);
    if relative.has_root() || relative.is_absolute() {
        return Err(format!(
            "'{uri}' is an absolute path; a glTF's files must be beneath its own directory"
        ));
    }
    let root = base
        .canonicalize()
        .map_err(|e| format!("{}: {e}", base.display()))?;
    let path = root.join(relative);
    let resolved = path
        .canonicalize()
        .map_err(|e| format!("{}: {e}", path.display()))?;
    if !resolved.starts_with(&root) {
        return Err(format!(
            "'{uri}' resolves to {}, outside the glTF's directory {}",
            resolved.display(),
            root.display()
        ));
    }
    let meta = std::fs::metadata(&resolved).map_err(|e| format!("{}: {e}", resolved.display()))?;
    if !meta.is_file() {
        return Err(format!("{} is not a regular file", resolved.display()));
    }
    if meta.len() > MAX_RESOURCE_BYTES {
        return Err(format!(
            "{} holds {} bytes, over the limit of {MAX_RESOURCE_BYTES}",
            resolved.display(),
            meta.len()
        ));
    }
    let file =
        std::fs::File::open(&resolved).map_err(|e| format!("{}: {e}", resolved.display()))?;
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    std::io::Read::read_to_end(
        &mut std::io::Read::take(file, MAX_RESOURCE_BYTES + 1),
        &mut bytes,
    )
    .map_err(|e| format!("{}: {e}", resolved.display()))?;
    if bytes.len() as u64 > MAX_RESOURCE_BYTES {
        return Err(format!(
            "{} grew past the limit of {MAX_RESOURCE_BYTES} bytes while it was read",
            resolved.display()
        ));
    }
    Ok(bytes)
}

/// The URI's scheme, if it has one (RFC 3986: a letter, then letters, digits, `+`, `-`, `.`).
/// A single letter is taken as a Windows drive, not a scheme.
fn scheme(uri: &str) -> Option<&str> {
    let (scheme, _) = uri.split_once(':')?;
    let mut chars = scheme.chars();
    let ok = chars.next().is_some_and(|c| c.is_ascii_alphabetic())
        && chars.all(|c| c.is_ascii_alphanumeric() || matches!(c, '+' | '-' | '.'));
    (ok && scheme.len() > 1).then_some(scheme)
}

/// `%XX` escapes decoded; a malformed escape is kept as written.
fn percent_decode(s: &str) -> Vec<u8> {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        let hex = |b: u8| (b as char).to_digit(16);
        if bytes[i] == b'%'
            && let (Some(&h), Some(&l)) = (bytes.get(i + 1), bytes.get(i + 2))
            && let (Some(h), Some(l)) = (hex(h), hex(l))
        {
            out.push((h * 16 + l) as u8);
            i += 3;
            continue;
        }
        out.push(bytes[i]);
        i += 1;
    }
    out
}

/// Standard or URL-safe base64; padding and whitespace are ignored.
fn base64(s: &str) -> Result<Vec<u8>, String> {
    let mut out = Vec::with_capacity(s.len() / 4 * 3);
    let mut acc: u32 = 0;
    let mut bits = 0;
    for c in s.bytes() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            b'=' | b' ' | b'\n' | b'\r' | b'\t' => continue,
            _ => return Err(format!("invalid base64 character {:?}", c as char)),
        };
        acc = (acc << 6) | u32::from(v);
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_round_trips_known_strings() {
        assert_eq!(base64("aGVsbG8=").unwrap(), b"hello");
        assert_eq!(base64("aGVsbG8h").unwrap(), b"hello!");
        assert_eq!(base64("").unwrap(), b"");
        assert!(base64("a*b").is_err());
    }

    #[test]
    fn percent_escapes_decode_and_bad_ones_survive() {
        assert_eq!(percent_decode("a%20b"), b"a b");
        assert_eq!(percent_decode("%zz%"), b"%zz%");
        assert_eq!(percent_decode("%FF"), [0xFF]);
    }

    #[test]
    fn schemes_are_told_from_drive_letters() {
        assert_eq!(scheme("http://x"), Some("http"));
        assert_eq!(scheme("C:/x.bin"), None);
        assert_eq!(scheme("scene.bin"), None);
    }

    /// What a hostile glTF's URIs may name: only regular files beneath its own directory.
    #[test]
    fn uris_stay_beneath_the_gltf_directory() {
        let dir = tempfile::tempdir().unwrap();
        let scene = dir.path().join("scene");
        std::fs::create_dir_all(scene.join("textures")).unwrap();
        std::fs::write(scene.join("textures/albedo.png"), b"png").unwrap();
        std::fs::write(scene.join("mesh bin.bin"), b"bin").unwrap();
        std::fs::write(dir.path().join("secret.txt"), b"secret").unwrap();
        std::os::unix::fs::symlink(dir.path().join("secret.txt"), scene.join("link.bin")).unwrap();
        std::os::unix::fs::symlink("/etc/hostname", scene.join("etc.bin")).unwrap();
        let base = Some(scene.as_path());

        assert_eq!(read_uri("textures/albedo.png", base).unwrap(), b"png");
        assert_eq!(
            read_uri("textures/../mesh%20bin.bin", base).unwrap(),
            b"bin"
        );
        assert_eq!(read_uri("data:,abc", base).unwrap(), b"abc");

        let refused = |uri: &str, why: &str| {
            let e = read_uri(uri, base).expect_err(uri);
            assert!(e.contains(why), "{uri}: {e}");
        };
        refused("../secret.txt", "outside the glTF's directory");
        refused("textures/../../secret.txt", "outside the glTF's directory");
        refused("%2E%2E/secret.txt", "outside the glTF's directory");
        refused("link.bin", "outside the glTF's directory");
        refused("etc.bin", "outside the glTF's directory");
        refused("/etc/passwd", "absolute path");
        refused("%2Fetc%2Fpasswd", "absolute path");
        refused("file:///etc/passwd", "scheme 'file:' refused");
        refused("FILE:/etc/passwd", "scheme 'FILE:' refused");
        refused("http://example.com/x.bin", "scheme 'http:' refused");
        refused("textures", "not a regular file");
        refused("missing.bin", "No such file");
    }

    /// A device file is refused before it is read: `/dev/zero` would read until memory ran out.
    #[test]
    fn device_files_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        std::os::unix::fs::symlink("/dev/zero", dir.path().join("zero.bin")).unwrap();
        std::fs::create_dir(dir.path().join("dev")).unwrap();
        let e = read_uri("zero.bin", Some(dir.path())).unwrap_err();
        assert!(e.contains("outside the glTF's directory"), "{e}");
        // The same device reached without a link: the base itself is /dev.
        let e = read_uri("zero", Some(Path::new("/dev"))).unwrap_err();
        assert!(e.contains("not a regular file"), "{e}");
    }

    #[test]
    fn glb_with_short_length_field_is_an_error_not_a_panic() {
        let mut b = b"glTF".to_vec();
        b.extend(2u32.to_le_bytes());
        b.extend(4u32.to_le_bytes());
        assert!(split(&b).is_err());
    }
}
