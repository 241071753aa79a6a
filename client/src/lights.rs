//! Light configurations on the wire: `bounce-types`' [`LightSet`] (docs/design.md §5's JSON form)
//! as proto messages for gRPC and as JSON for WebSocket and HTTP.
//!
//! Nothing is validated here: the server is the one judge of a light configuration, and its
//! refusal names the field (`lights[0].intensity: ...`).

use bounce_types::light::LightSet;

pub use bounce_wire::lights::to_proto;

/// The `lights` array of the JSON form.
pub fn to_json(set: &LightSet) -> serde_json::Value {
    // A LightSet is plain numbers and strings: serialising it cannot fail, and if it somehow
    // did the server would refuse the null with a message naming `lights`.
    serde_json::to_value(&set.lights).unwrap_or(serde_json::Value::Null)
}

#[cfg(test)]
mod tests {
    use super::*;

    const DESIGN_EXAMPLE: &str = r#"{"lights": [
        {"type": "point", "position": [0, 1.5, 0], "color": [1, 1, 1], "intensity": 10},
        {"type": "directional", "direction": [0.3, -1, 0.2], "color": [1, 0.95, 0.9], "intensity": 3},
        {"type": "spot", "position": [0, 2, 0], "direction": [0, -1, 0], "color": [1, 1, 1],
         "intensity": 50, "inner_cone_angle": 0.3, "outer_cone_angle": 0.6, "range": 4, "name": "s"}
    ]}"#;

    #[test]
    fn proto_and_json_round_trip_through_the_servers_readers() {
        let set = LightSet::from_json(DESIGN_EXAMPLE).unwrap();
        let back = bounce_wire::lights::light_set(&to_proto(&set)).unwrap();
        assert_eq!(back, set);
        let json = serde_json::json!({ "lights": to_json(&set) }).to_string();
        assert_eq!(LightSet::from_json(&json).unwrap(), set);
    }
}
