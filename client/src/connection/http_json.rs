//! The server's HTTP JSON routes: one HTTP/1.1 request on its own connection (hyper), the
//! answer's body bounded, a refusal's `{"code", "message"}` turned into [`ClientError::Refused`].

use std::time::Duration;

use bytes::Bytes;
use http::{Method, Request, StatusCode, header};
use http_body_util::{BodyExt, Full, Limited};
use hyper_util::rt::TokioIo;
use serde::Deserialize;
use tokio::net::TcpStream;

use super::MAX_MESSAGE_BYTES;
use super::address::Address;
use crate::error::{ClientError, Refusal};

pub(super) struct Call<'a> {
    pub address: &'a Address,
    pub method: Method,
    pub path: String,
    pub token: Option<&'a str>,
    pub body: Option<Vec<u8>>,
    pub timeout: Duration,
}

impl Call<'_> {
    /// The answer's body when its status is a success.
    pub async fn send(self) -> Result<Bytes, ClientError> {
        let what = format!("{} {}", self.method, self.path);
        let after = self.timeout;
        tokio::time::timeout(after, self.exchange())
            .await
            .map_err(|_| ClientError::Timeout { what, after })?
    }

    async fn exchange(self) -> Result<Bytes, ClientError> {
        let authority = self.address.authority();
        let stream = TcpStream::connect((self.address.host.as_str(), self.address.port))
            .await
            .map_err(|e| ClientError::Connect {
                url: format!("http://{authority}"),
                message: e.to_string(),
            })?;
        let _ = stream.set_nodelay(true);
        let (mut sender, connection) = hyper::client::conn::http1::handshake(TokioIo::new(stream))
            .await
            .map_err(transport)?;
        // Drives the connection until the answer is read and `sender` dropped.
        tokio::spawn(async move {
            let _ = connection.await;
        });

        let mut request = Request::builder()
            .method(self.method)
            .uri(&self.path)
            .header(header::HOST, authority)
            .header(header::ACCEPT, "application/json");
        if let Some(t) = self.token {
            request = request.header(header::AUTHORIZATION, format!("Bearer {t}"));
        }
        let body = match self.body {
            Some(b) => {
                request = request.header(header::CONTENT_TYPE, "application/json");
                Full::new(Bytes::from(b))
            }
            None => Full::new(Bytes::new()),
        };
        let request = request.body(body).map_err(|_| ClientError::InvalidToken)?;
        let response = sender.send_request(request).await.map_err(transport)?;
        let status = response.status();
        let body = Limited::new(response.into_body(), MAX_MESSAGE_BYTES)
            .collect()
            .await
            .map_err(|e| ClientError::Transport(format!("reading the answer: {e}")))?
            .to_bytes();
        if status.is_success() {
            Ok(body)
        } else {
            Err(refusal(status, &body))
        }
    }
}

fn transport(e: hyper::Error) -> ClientError {
    ClientError::Transport(e.to_string())
}

#[derive(Deserialize)]
struct ErrorBody {
    code: String,
    message: String,
}

/// A refusal from its JSON body, or from the status alone when the body is not the server's.
pub(super) fn refusal(status: StatusCode, body: &[u8]) -> ClientError {
    if let Ok(e) = serde_json::from_slice::<ErrorBody>(body) {
        return ClientError::Refused {
            code: Refusal::from_json_code(&e.code),
            message: e.message,
        };
    }
    let code = match status {
        StatusCode::BAD_REQUEST => Refusal::InvalidArgument,
        StatusCode::UNAUTHORIZED | StatusCode::FORBIDDEN => Refusal::Unauthenticated,
        StatusCode::NOT_FOUND => Refusal::NotFound,
        StatusCode::PAYLOAD_TOO_LARGE => Refusal::ResourceExhausted,
        StatusCode::SERVICE_UNAVAILABLE | StatusCode::BAD_GATEWAY | StatusCode::GATEWAY_TIMEOUT => {
            Refusal::Unavailable
        }
        s if s.is_server_error() => Refusal::Internal,
        s => Refusal::Other(s.as_u16().to_string()),
    };
    // A proxy's or another program's page: its start is the best explanation there is.
    let text = String::from_utf8_lossy(&body[..body.len().min(200)]).into_owned();
    ClientError::Refused {
        code,
        message: format!("HTTP {status}: {text}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refusals_read_the_body_or_fall_back_to_the_status() {
        let e = refusal(
            StatusCode::NOT_FOUND,
            br#"{"code":"not_found","message":"unknown session \"x\""}"#,
        );
        assert_eq!(e.refusal(), Some(&Refusal::NotFound));
        assert!(e.to_string().contains("unknown session"));
        let e = refusal(StatusCode::BAD_GATEWAY, b"<html>bad gateway</html>");
        assert_eq!(e.refusal(), Some(&Refusal::Unavailable));
        assert!(e.to_string().contains("502"));
        assert!(e.is_transient());
        let e = refusal(StatusCode::IM_A_TEAPOT, b"");
        assert_eq!(e.refusal(), Some(&Refusal::Other("418".into())));
    }
}
