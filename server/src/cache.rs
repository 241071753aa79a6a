//! Answers that browsers may cache but must revalidate: a strong `ETag` from the bytes,
//! `If-None-Match` answered with 304, and `Cache-Control: no-cache` so that a changed scene or an
//! edited page is seen on the next load while an unchanged one costs a 304.

use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use bytes::Bytes;
use sha1::{Digest, Sha1};

/// The strong entity tag of `bytes`, quoted as the header carries it: a SHA-1 of the content,
/// so the same bytes get the same tag on every server and across restarts.
pub fn etag_of(bytes: &[u8]) -> String {
    let digest = Sha1::digest(bytes);
    let hex: String = digest.iter().map(|b| format!("{b:02x}")).collect();
    format!("\"{hex}\"")
}

/// Whether the request's `If-None-Match` names `etag`. Compared weakly (RFC 9110 §13.1.2), so a
/// tag the compression layer weakened still matches.
pub fn not_modified(headers: &HeaderMap, etag: &str) -> bool {
    let strip = |t: &str| t.trim().trim_start_matches("W/").to_string();
    let ours = strip(etag);
    headers
        .get_all(header::IF_NONE_MATCH)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .any(|t| t.trim() == "*" || strip(t) == ours)
}

/// 200 with `bytes`, or 304 when the client has them already.
pub fn respond(headers: &HeaderMap, bytes: Bytes, etag: &str, content_type: &str) -> Response {
    let etag_value = HeaderValue::from_str(etag).ok();
    let mut common = HeaderMap::new();
    if let Some(v) = etag_value {
        common.insert(header::ETAG, v);
    }
    common.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    if not_modified(headers, etag) {
        return (StatusCode::NOT_MODIFIED, common).into_response();
    }
    if let Ok(v) = HeaderValue::from_str(content_type) {
        common.insert(header::CONTENT_TYPE, v);
    }
    (StatusCode::OK, common, bytes).into_response()
}

/// Marks the tag weak when the body was compressed: the compressed bytes are not the bytes the
/// strong tag names (RFC 9110 §8.8.3), which is what nginx does too.
pub async fn weaken_compressed_etag(mut response: Response) -> Response {
    if response.headers().contains_key(header::CONTENT_ENCODING)
        && let Some(tag) = response.headers().get(header::ETAG)
        && let Ok(t) = tag.to_str()
        && !t.starts_with("W/")
        && let Ok(weak) = HeaderValue::from_str(&format!("W/{t}"))
    {
        response.headers_mut().insert(header::ETAG, weak);
    }
    response
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tags_match_strongly_weakly_in_lists_and_by_star() {
        let tag = etag_of(b"hello");
        assert_eq!(tag, "\"aaf4c61ddcc5e8a2dabede0f3b482cd9aea9434d\"");
        let with = |v: &str| {
            let mut h = HeaderMap::new();
            h.insert(header::IF_NONE_MATCH, HeaderValue::from_str(v).unwrap());
            h
        };
        assert!(not_modified(&with(&tag), &tag));
        assert!(not_modified(&with(&format!("W/{tag}")), &tag));
        assert!(not_modified(&with(&format!("\"x\", {tag}")), &tag));
        assert!(not_modified(&with("*"), &tag));
        assert!(!not_modified(&with("\"x\""), &tag));
        assert!(!not_modified(&HeaderMap::new(), &tag));
    }
}
