//! Compiles `proto/bounce/v1/bounce.proto` with `protox` (pure Rust, so no system `protoc`) and
//! writes the file descriptor set that the server's gRPC reflection serves.

use std::path::PathBuf;

use prost::Message;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let proto_root = PathBuf::from("../proto");
    let file = "bounce/v1/bounce.proto";
    println!("cargo:rerun-if-changed=../proto/{file}");
    let fds = protox::compile([file], [&proto_root])?;
    let out = PathBuf::from(std::env::var("OUT_DIR")?);
    std::fs::write(out.join("bounce_v1_descriptor.bin"), fds.encode_to_vec())?;
    tonic_prost_build::configure()
        // A message that does not decode is the client's error (see src/codec.rs).
        .codec_path("crate::codec::StrictCodec")
        // Frames are encoded once and shared by every viewer: `Bytes` clones are reference counts.
        .bytes(".bounce.v1.Frame.data")
        .bytes(".bounce.v1.Frame.probes")
        .compile_fds(fds)?;
    Ok(())
}
