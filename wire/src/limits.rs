//! How large a message may be, in each direction: the server refuses a request over
//! [`MAX_REQUEST_BYTES`] and a client a message over [`MAX_MESSAGE_BYTES`]. A valid light set
//! always fits a request (checked below when this compiles), so a client that validates its
//! lights never has one refused for its size.

/// Largest request the server accepts (a gRPC message, an HTTP body, a WebSocket message): 256
/// lights take a few tens of kilobytes, so 1 MiB is generous and still refuses a client that
/// tries to make the server buffer megabytes.
pub const MAX_REQUEST_BYTES: usize = 1 << 20;

/// The largest message (a layout, a frame) a client reads: 64 MiB, a frame of 16 million
/// patches. A server that sends more is refused rather than buffered.
pub const MAX_MESSAGE_BYTES: usize = 64 << 20;

// A request carries at most `MAX_LIGHTS` lights, each with a name of at most `MAX_NAME_BYTES`
// and a few numbers: the limit must hold the largest valid set, or a valid set would be refused.
const _: () = {
    use bounce_types::light::{MAX_LIGHTS, MAX_NAME_BYTES};
    // A light's JSON without its name: type, colour, intensity, range, position, direction and
    // cone angles, each number at most 24 characters.
    const LIGHT_JSON_BYTES: usize = 512;
    assert!(MAX_LIGHTS * (MAX_NAME_BYTES * 6 + LIGHT_JSON_BYTES) <= MAX_REQUEST_BYTES);
};
