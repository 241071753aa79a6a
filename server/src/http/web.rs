//! The browser page: every file of `web/public/` built into the binary (the table `build.rs`
//! writes), served at its path below the root, `/` answering `index.html`. With
//! [`crate::HubConfig::web_dir`] the files are read from that directory on every request instead,
//! so the page can be worked on without rebuilding the server.
//!
//! A request path is only ever looked up: in the table, or, from disk, after refusing every path
//! that is not plain names joined by `/` (no `..`, `.`, empty parts, backslashes or NULs), so no
//! request reaches a file outside the page's directory.

use std::collections::HashMap;
use std::path::Path;
use std::sync::OnceLock;

use axum::extract::{Request, State};
use axum::http::Method;
use axum::response::{IntoResponse, Response};
use bytes::Bytes;

use super::error::{ApiError, ErrorCode};
use super::state::AppState;
use crate::cache;

include!(concat!(env!("OUT_DIR"), "/web_files.rs"));

/// An embedded file, ready to send.
struct StaticFile {
    bytes: Bytes,
    etag: String,
    content_type: &'static str,
}

/// The embedded files by path, their tags computed once.
fn embedded() -> &'static HashMap<&'static str, StaticFile> {
    static FILES: OnceLock<HashMap<&'static str, StaticFile>> = OnceLock::new();
    FILES.get_or_init(|| {
        WEB_FILES
            .iter()
            .map(|&(path, bytes)| {
                let file = StaticFile {
                    bytes: Bytes::from_static(bytes),
                    etag: cache::etag_of(bytes),
                    content_type: content_type(path),
                };
                (path, file)
            })
            .collect()
    })
}

/// The paths of the embedded files, sorted.
pub fn embedded_paths() -> impl Iterator<Item = &'static str> {
    WEB_FILES.iter().map(|&(path, _)| path)
}

/// The `Content-Type` of a file by its extension.
pub fn content_type(path: &str) -> &'static str {
    let ext = path
        .rsplit_once('.')
        .map(|(_, e)| e.to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "html" | "htm" => "text/html; charset=utf-8",
        "js" | "mjs" => "text/javascript; charset=utf-8",
        "css" => "text/css; charset=utf-8",
        "json" | "map" => "application/json",
        "webmanifest" => "application/manifest+json",
        "svg" => "image/svg+xml",
        "png" => "image/png",
        "jpg" | "jpeg" => "image/jpeg",
        "webp" => "image/webp",
        "ico" => "image/x-icon",
        "ktx2" => "image/ktx2",
        "glb" => "model/gltf-binary",
        "gltf" => "model/gltf+json",
        "bin" => "application/octet-stream",
        "wasm" => "application/wasm",
        "txt" | "md" => "text/plain; charset=utf-8",
        _ => "application/octet-stream",
    }
}

/// The page's file a request path names, without the leading `/`: `index.html` for `/` (and
/// for a directory's trailing `/`), or `None` for a path no file of the page can have.
pub fn file_path(request_path: &str) -> Option<String> {
    let decoded = percent_decode(request_path.strip_prefix('/')?)?;
    let mut path = decoded;
    if path.is_empty() || path.ends_with('/') {
        path.push_str("index.html");
    }
    let plain = path.split('/').all(|part| {
        !part.is_empty()
            && part != "."
            && part != ".."
            && !part.contains(['\\', '\0'])
            && !part.contains(':')
    });
    plain.then_some(path)
}

/// `%XX` escapes decoded; `None` for a malformed escape or a result that is not UTF-8.
fn percent_decode(s: &str) -> Option<String> {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%' {
            let hex = bytes.get(i + 1..i + 3)?;
            let hex = std::str::from_utf8(hex).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            out.push(bytes[i]);
            i += 1;
        }
    }
    String::from_utf8(out).ok()
}

/// The router's fallback: a file of the page for `GET` and `HEAD`, else the JSON 404 every
/// unknown route gets.
pub(crate) async fn serve(State(state): State<AppState>, request: Request) -> Response {
    let no_route = || ApiError::new(ErrorCode::NotFound, "no such route").into_response();
    if request.method() != Method::GET && request.method() != Method::HEAD {
        return no_route();
    }
    let Some(path) = file_path(request.uri().path()) else {
        return no_route();
    };
    let headers = request.headers();
    match state.hub.web_dir() {
        None => match embedded().get(path.as_str()) {
            Some(f) => cache::respond(headers, f.bytes.clone(), &f.etag, f.content_type),
            None => no_route(),
        },
        Some(dir) => match read_from(dir, &path).await {
            Ok(Some(bytes)) => {
                let etag = cache::etag_of(&bytes);
                cache::respond(headers, Bytes::from(bytes), &etag, content_type(&path))
            }
            Ok(None) => no_route(),
            Err(e) => ApiError::new(
                ErrorCode::Internal,
                format!(
                    "reading {path} from the web directory {}: {e}",
                    dir.display()
                ),
            )
            .into_response(),
        },
    }
}

/// The file `path` (checked by [`file_path`]) of `dir`, or `None` when there is no such file.
/// Read off the runtime's threads.
async fn read_from(dir: &Path, path: &str) -> std::io::Result<Option<Vec<u8>>> {
    let full = dir.join(path);
    let read = move || match std::fs::metadata(&full) {
        Ok(m) if m.is_file() => std::fs::read(&full).map(Some),
        Ok(_) => Ok(None),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) if e.kind() == std::io::ErrorKind::NotADirectory => Ok(None),
        Err(e) => Err(e),
    };
    tokio::task::spawn_blocking(read)
        .await
        .map_err(std::io::Error::other)?
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paths_map_to_files_and_never_climb_out() {
        assert_eq!(file_path("/").as_deref(), Some("index.html"));
        assert_eq!(
            file_path("/vendor/three/three.module.js").as_deref(),
            Some("vendor/three/three.module.js")
        );
        assert_eq!(file_path("/docs/").as_deref(), Some("docs/index.html"));
        assert_eq!(file_path("/a%20b.js").as_deref(), Some("a b.js"));
        for bad in [
            "/../Cargo.toml",
            "/vendor/../../etc/passwd",
            "/%2e%2e/secret",
            "/a/./b",
            "//etc/passwd",
            "/a\\..\\b",
            "/%00",
            "/%zz",
            "/C:/x",
            "no-slash",
        ] {
            assert_eq!(file_path(bad), None, "{bad}");
        }
    }

    #[test]
    fn the_table_holds_the_page_and_three() {
        let paths: Vec<&str> = embedded_paths().collect();
        assert!(paths.contains(&"index.html"), "{paths:?}");
        assert!(paths.contains(&"vendor/three/three.module.js"), "{paths:?}");
        assert!(
            paths
                .iter()
                .all(|p| file_path(&format!("/{p}")).as_deref() == Some(*p))
        );
    }

    #[test]
    fn content_types_by_extension() {
        assert_eq!(content_type("index.html"), "text/html; charset=utf-8");
        assert_eq!(content_type("a/b.MJS"), "text/javascript; charset=utf-8");
        assert_eq!(content_type("m.glb"), "model/gltf-binary");
        assert_eq!(content_type("LICENSE"), "application/octet-stream");
    }
}
