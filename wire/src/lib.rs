//! `bounce-wire`: what travels between the lighting service and its clients, defined once for both.
//!
//! It owns the protobuf messages and the gRPC client and server stubs generated from
//! `proto/bounce/v1/bounce.proto` ([`proto`], compiled with `protox`, so no system `protoc`), the
//! gRPC codec that answers undecodable messages as the sender's error ([`codec`]), the frame byte
//! layout with its RGB9E5 payload ([`frame`]), and the light messages' conversion to and from
//! [`bounce_types::light::LightSet`] with the JSON form's field paths in its errors ([`lights`]),
//! the text messages a client sends on a session WebSocket ([`text`]), a scene's patch layout as
//! it is sent ([`layout`]) and how large a message may be each way ([`limits`]).
//!
//! Not here: sessions, scenes, engines and the front ends (`bounce-server`), connecting and
//! rendering (`bounce-client`), the lights' own validation (`bounce-types`). A thin client depends
//! on this crate and `bounce-types` alone.

pub mod codec;
pub mod frame;
pub mod layout;
pub mod lights;
pub mod limits;
pub mod text;

pub use frame::Frame;

/// Code generated from `proto/bounce/v1/bounce.proto`: messages, the server trait and a client.
pub mod proto {
    #![allow(clippy::all, missing_docs)]
    tonic::include_proto!("bounce.v1");

    /// The proto's file descriptor set, served by gRPC reflection.
    pub const FILE_DESCRIPTOR_SET: &[u8] =
        tonic::include_file_descriptor_set!("bounce_v1_descriptor");
}
