//! A text message on a session WebSocket, on arbitrary bytes, through the server's own parser
//! (`bounce_wire::text::parse_client_text`: the message's JSON, then its light set validated as
//! every front end does). Messages over the server's 1 MiB limit never reach it, and neither does
//! text that is not UTF-8 (the WebSocket layer refuses both), so neither is tried here.
#![no_main]

use bounce_wire::text::{ClientText, parse_client_text};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(ClientText::SetLights {
        lights: Ok(set), ..
    }) = parse_client_text(text)
    {
        assert!(
            set.validate().is_ok(),
            "an accepted light set must validate"
        );
    }
});
