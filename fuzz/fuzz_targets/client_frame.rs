//! A frame as the client library receives it (a WebSocket binary message or gRPC's
//! `Frame.data`), on arbitrary bytes: `Frame::parse`, then the irradiance volume's `apply` and a
//! sample, as `bounce view` and `bounce render` do with every frame. The volume is a fixed small
//! layout; a frame for another patch count must be refused, never written out of bounds.
#![no_main]

use std::sync::OnceLock;

use bounce_client::{Frame, Layout, Volume};
use bytes::Bytes;
use glam::Vec3;
use libfuzzer_sys::fuzz_target;

/// A 2×2×1 grid with four patches, as `GET /v1/scenes/{name}/layout` sends it.
const LAYOUT: &str = r#"{"scene":"fuzz","origin":[0,0,0],"voxel_size":0.5,"dims":[2,2,1],
"patch_count":4,"voxels":[0,0,0, 1,0,0, 0,1,0, 1,1,0],"faces":[0,1,2,3]}"#;

fn layout() -> &'static Layout {
    static LAYOUT_ONCE: OnceLock<Layout> = OnceLock::new();
    LAYOUT_ONCE.get_or_init(|| Layout::from_json(LAYOUT.as_bytes()).expect("the fixed layout"))
}

fuzz_target!(|data: &[u8]| {
    let Ok(frame) = Frame::parse(Bytes::copy_from_slice(data)) else {
        return;
    };
    let irradiance = frame.irradiance();
    assert_eq!(irradiance.len(), frame.header.patch_count as usize);
    let Ok(mut volume) = Volume::new(layout()) else {
        panic!("the fixed layout makes a volume");
    };
    if volume.apply(&frame).is_ok() {
        let _ = volume.sample(Vec3::new(0.5, 0.5, 0.25), Vec3::Z);
    }
});
