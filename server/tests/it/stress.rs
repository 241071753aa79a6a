//! Very bright lights end to end (issue 8, docs/design.md §4): through the real server on loopback,
//! gRPC and WebSocket, a light bright enough to push the indirect irradiance past RGB9E5's range
//! gives frames of finite values clamped to the format's largest, flagged in the frame header and
//! counted in the metrics; never an infinity or a NaN on the wire.

use bounce_server::frame::{FLAG_CLAMPED, FLAG_NON_FINITE, RGB9E5_MAX};

use crate::common::*;

/// Reads the first frame of a subscription.
async fn first_frame(stream: &mut Streaming<proto::Frame>) -> Frame {
    let f = tokio::time::timeout(PATIENCE, stream.message())
        .await
        .expect("no frame in time")
        .expect("frame")
        .expect("stream ended");
    Frame::parse(f.data).expect("frame bytes")
}

fn summary(frame: &Frame) -> (f32, usize) {
    let values = frame.irradiance();
    for rgb in &values {
        assert!(
            rgb.iter()
                .all(|v| v.is_finite() && (0.0..=RGB9E5_MAX).contains(v)),
            "{rgb:?}"
        );
    }
    let max = values.iter().flatten().fold(0.0f32, |m, v| m.max(*v));
    let at_max = values
        .iter()
        .flatten()
        .filter(|v| **v == RGB9E5_MAX)
        .count();
    (max, at_max)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_absurdly_bright_light_is_clamped_and_flagged_end_to_end() {
    let server = TestServer::start().await;
    let mut c = server.client().await;
    let http = reqwest::Client::new();

    // 1e30 cd is absurd but valid; f32::MAX is the brightest a light can be.
    for intensity in [1e30f32, f32::MAX] {
        let (id, _) = create_session(&mut c, vec![point(intensity)]).await;
        let mut stream = subscribe(&mut c, &id).await;
        let frame = first_frame(&mut stream).await;
        let (max, at_max) = summary(&frame);
        eprintln!(
            "intensity {intensity:e}: gRPC frame flags {:#b}, largest value {max} ({at_max} \
             components at RGB9E5's max of {})",
            frame.header.flags,
            3 * frame.header.patch_count
        );
        // Clamped, and not "non-finite": the engine's output stays finite even here.
        assert_eq!(frame.header.flags, FLAG_CLAMPED, "intensity {intensity:e}");
        assert_eq!(max, RGB9E5_MAX);
        assert!(at_max > 0);

        // The WebSocket carries the same bytes for the same session.
        let mut ws = WsClient::connect(&server.ws_url(&id, None)).await;
        ws.frames_until(1).await;
        let ws_frame = ws.last.clone().expect("a frame");
        assert_eq!(ws_frame.header.flags, FLAG_CLAMPED);
        assert_eq!(ws_frame.irradiance(), frame.irradiance());

        // Back to an ordinary light: the next frame is unflagged.
        let r = c
            .set_lights(proto::SetLightsRequest {
                session_id: id.clone(),
                lights: vec![point(2.0)],
                ..Default::default()
            })
            .await
            .expect("set lights")
            .into_inner();
        read_until(&mut stream, r.lights_version).await;
        ws.frames_until(r.lights_version).await;
        let calm = ws.last.clone().expect("a frame");
        assert_eq!(calm.header.flags & (FLAG_CLAMPED | FLAG_NON_FINITE), 0);
        let (max, _) = summary(&calm);
        assert!(max > 0.0 && max < RGB9E5_MAX, "{max}");
    }

    // The operator sees it too.
    let metrics = http
        .get(server.url("/metrics"))
        .send()
        .await
        .expect("GET /metrics")
        .text()
        .await
        .expect("body");
    let line = metrics
        .lines()
        .find(|l| l.starts_with(r#"bounce_frames_flagged_total{flag="clamped"}"#))
        .unwrap_or_else(|| panic!("no clamped-frame counter in {metrics}"));
    let count: u64 = line
        .rsplit(' ')
        .next()
        .and_then(|v| v.parse().ok())
        .expect("a count");
    eprintln!("metrics: {line}");
    assert!(count >= 2, "{line}");
    assert!(
        !metrics.contains(r#"flag="non_finite""#),
        "no frame should have been non-finite: {metrics}"
    );
    server.stop().await;
}
