//! Raw bytes of a glTF asset: the GLB container, and the buffers and images its URIs name.
//!
//! Done here rather than by `gltf::import`, which fails the whole import on one missing image and
//! panics on some malformed input (a GLB length field below the header size, a relative URI whose
//! percent-escapes are not UTF-8).

use std::path::{Path, PathBuf};

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

/// Reads what a URI names: a `data:` URI, a `file:` URI, or a path relative to `base`.
pub(crate) fn read_uri(uri: &str, base: Option<&Path>) -> Result<Vec<u8>, String> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (header, payload) = rest.split_once(',').ok_or("data URI without a comma")?;
        return if header.ends_with(";base64") {
            base64(payload)
        } else {
            Ok(percent_decode(payload))
        };
    }
    let path = match scheme(uri) {
        Some(s) if s.eq_ignore_ascii_case("file") => {
            let rest = &uri[s.len() + 1..];
            let rest = rest.strip_prefix("//").unwrap_or(rest);
            PathBuf::from(String::from_utf8_lossy(&percent_decode(rest)).into_owned())
        }
        Some(s) => return Err(format!("unsupported URI scheme '{s}'")),
        None => {
            let base = base.ok_or_else(|| {
                format!("'{uri}' is an external file, but no base directory was given")
            })?;
            base.join(String::from_utf8_lossy(&percent_decode(uri)).as_ref())
        }
    };
    std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))
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

    #[test]
    fn glb_with_short_length_field_is_an_error_not_a_panic() {
        let mut b = b"glTF".to_vec();
        b.extend(2u32.to_le_bytes());
        b.extend(4u32.to_le_bytes());
        assert!(split(&b).is_err());
    }
}
