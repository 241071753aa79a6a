//! Light configuration JSON on arbitrary bytes, through the one parser every front end uses:
//! `LightSet::from_json` (the CLI's `--lights` files, `PUT /v1/sessions/{id}/lights` and, through
//! `bounce_server::http`, the lights of `POST /v1/sessions`). A set that parses must validate and
//! survive the conversion the gRPC front end and the client library make of it.
#![no_main]

use bounce_core::light::LightSet;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(set) = LightSet::from_json(text) else {
        return;
    };
    assert!(set.validate().is_ok(), "a parsed light set must validate");
    // Round trips: to gRPC's messages and back (the server's own conversion), and to the JSON the
    // client sends and back through the parser.
    let proto = bounce_wire::lights::to_proto(&set);
    let _ = bounce_wire::lights::light_set(&proto);
    // The client sends the `lights` array; the document around it is the server's.
    let json = format!(r#"{{"lights":{}}}"#, bounce_client::lights::to_json(&set));
    assert!(
        LightSet::from_json(&json).is_ok(),
        "a valid light set must parse again from the client's JSON: {json}"
    );
});
