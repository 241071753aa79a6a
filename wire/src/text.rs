//! The text messages a client sends on a session WebSocket, read as the server reads them:
//! `{"type": "set_lights", "lights": [...], "token"?}` and `{"type": "ping"}`. What the server
//! answers and the session they act on are the server's business.

use serde::Deserialize;

use bounce_types::light::{LightError, LightSet};

/// A client's text message on a session WebSocket, as [`parse_client_text`] reads it.
#[derive(Debug)]
pub enum ClientText {
    /// `{"type": "ping"}`.
    Ping,
    /// `{"type": "set_lights", "lights": [...], "token"?}`.
    SetLights {
        /// The lights, read and validated as every front end does. An invalid set is kept as
        /// its error rather than refusing the message, because the server answers a missing or
        /// wrong token before a bad light set.
        lights: Result<LightSet, LightError>,
        token: Option<String>,
    },
}

/// A text message that is not one of [`ClientText`]'s: what is wrong with it, as the client
/// reads it in the server's error reply.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct TextError(pub String);

/// Parses one text message from a session WebSocket: the server's own reading of everything a
/// client may send there, short of the session it acts on (the `ws_text` fuzz target in `fuzz/`
/// runs exactly this code).
pub fn parse_client_text(text: &str) -> Result<ClientText, TextError> {
    let message: ClientMessage =
        serde_json::from_str(text).map_err(|e| TextError(format!("message: {e}")))?;
    Ok(match message {
        ClientMessage::Ping => ClientText::Ping,
        ClientMessage::SetLights { lights, token } => ClientText::SetLights {
            lights: light_set(lights),
            token,
        },
    })
}

/// The `lights` array of a JSON message as a validated light set, through the one JSON reader
/// (`LightSet::from_json`), so its errors carry the same field paths everywhere.
pub fn light_set(lights: serde_json::Value) -> Result<LightSet, LightError> {
    let document = serde_json::json!({ "lights": lights });
    LightSet::from_json(&document.to_string())
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
enum ClientMessage {
    SetLights {
        lights: serde_json::Value,
        #[serde(default)]
        token: Option<String>,
    },
    Ping,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_parse_and_a_bad_light_set_is_kept_as_its_error() {
        assert!(matches!(
            parse_client_text(r#"{"type":"ping"}"#),
            Ok(ClientText::Ping)
        ));
        let Ok(ClientText::SetLights { lights, token }) = parse_client_text(
            r#"{"type":"set_lights","lights":[{"type":"point","position":[0,1,0],"intensity":5}],"token":"t"}"#,
        ) else {
            panic!("a valid set_lights message");
        };
        assert_eq!(lights.map(|s| s.lights.len()), Ok(1));
        assert_eq!(token.as_deref(), Some("t"));
        let Ok(ClientText::SetLights { lights, .. }) =
            parse_client_text(r#"{"type":"set_lights","lights":[{"type":"point"}]}"#)
        else {
            panic!("a bad light set is still a set_lights message");
        };
        assert!(lights.is_err());
        // (A ping with extra fields is a ping: serde's deny_unknown_fields does not reach the
        // unit variants of an internally tagged enum.)
        for bad in [r#"{"type":"reboot"}"#, r#"{"set_lights":[]}"#, "not json"] {
            let e = parse_client_text(bad).expect_err(bad);
            assert!(e.0.starts_with("message: "), "{bad}: {e}");
        }
    }
}
