//! Server addresses: `http://host:port` for gRPC, `ws://host:port` for WebSocket (with its
//! HTTP JSON routes on the same port), and the escaping of names put into paths.

use http::Uri;

use crate::error::ClientError;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scheme {
    Grpc,
    WebSocket,
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Address {
    pub scheme: Scheme,
    pub host: String,
    pub port: u16,
}

impl Address {
    pub fn parse(url: &str) -> Result<Address, ClientError> {
        let bad = |reason: &str| ClientError::Url {
            url: url.to_string(),
            reason: reason.to_string(),
        };
        let uri: Uri = url.parse().map_err(|e| bad(&format!("{e}")))?;
        let scheme = match uri.scheme_str() {
            Some("http") => Scheme::Grpc,
            Some("ws") => Scheme::WebSocket,
            Some("https" | "wss") => return Err(bad("TLS is not supported by this client")),
            Some(other) => {
                return Err(bad(&format!(
                    "scheme {other:?}: use http:// (gRPC) or ws:// (WebSocket)"
                )));
            }
            None => return Err(bad("no scheme: use http:// (gRPC) or ws:// (WebSocket)")),
        };
        let Some(authority) = uri.authority() else {
            return Err(bad("no host"));
        };
        if authority.as_str().contains('@') {
            return Err(bad("user information is not supported"));
        }
        if !matches!(uri.path(), "" | "/") || uri.query().is_some() {
            return Err(bad(
                "give the server's address only (no path or query): the routes are this client's",
            ));
        }
        // Brackets off an IPv6 literal; they come back in `authority()`.
        let host = authority
            .host()
            .trim_start_matches('[')
            .trim_end_matches(']')
            .to_string();
        Ok(Address {
            scheme,
            host,
            port: authority.port_u16().unwrap_or(80),
        })
    }

    /// `host:port`, as a Host header and a URL carry it.
    pub fn authority(&self) -> String {
        if self.host.contains(':') {
            format!("[{}]:{}", self.host, self.port)
        } else {
            format!("{}:{}", self.host, self.port)
        }
    }
}

/// Percent-encodes everything but RFC 3986's unreserved characters, so a session id, scene name
/// or token is always one path segment or query value.
pub(crate) fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for b in s.bytes() {
        if b.is_ascii_alphanumeric() || matches!(b, b'-' | b'.' | b'_' | b'~') {
            out.push(char::from(b));
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_parse() {
        assert_eq!(
            Address::parse("http://127.0.0.1:50051").unwrap(),
            Address {
                scheme: Scheme::Grpc,
                host: "127.0.0.1".into(),
                port: 50051
            }
        );
        let ws = Address::parse("ws://[::1]:8080/").unwrap();
        assert_eq!(
            (ws.scheme, ws.host.as_str(), ws.port),
            (Scheme::WebSocket, "::1", 8080)
        );
        assert_eq!(ws.authority(), "[::1]:8080");
        assert_eq!(Address::parse("ws://example.org").unwrap().port, 80);
        for (url, why) in [
            ("127.0.0.1:50051", "scheme"),
            ("https://a:1", "TLS"),
            ("ftp://a:1", "scheme"),
            ("ws://a:1/v1/sessions", "no path"),
            ("http://a:1?x=1", "no path"),
            ("http://u@a:1", "user"),
            ("", "not a server address"),
        ] {
            let err = Address::parse(url).unwrap_err().to_string();
            assert!(err.contains(why), "{url}: {err}");
        }
    }

    #[test]
    fn escaping_keeps_one_segment() {
        assert_eq!(escape("cornell-box_1.x~"), "cornell-box_1.x~");
        assert_eq!(escape("a/b?c d#é"), "a%2Fb%3Fc%20d%23%C3%A9");
    }
}
