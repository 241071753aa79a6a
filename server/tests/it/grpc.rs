//! The gRPC service end to end: real servers, real tonic clients.

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn list_scenes_and_layout_describe_the_baked_file() {
    let server = TestServer::start().await;
    let mut c = server.client().await;
    let baked = baked();
    let list = c
        .list_scenes(proto::ListScenesRequest {})
        .await
        .expect("list")
        .into_inner();
    // The broken file was skipped; the good one serves.
    assert_eq!(list.scenes.len(), 1, "{list:?}");
    assert_eq!(list.scenes[0].name, SCENE);
    assert_eq!(list.scenes[0].patch_count as usize, baked.layout.len());
    assert_eq!(list.scenes[0].codec, baked.transport.codec);
    assert!(list.engine.starts_with("cpu"), "{}", list.engine);

    let layout = c
        .get_layout(proto::GetLayoutRequest {
            scene: SCENE.into(),
        })
        .await
        .expect("layout")
        .into_inner();
    let l = &baked.layout;
    assert_eq!(layout.origin, l.origin.to_vec());
    assert_eq!(layout.voxel_size, l.voxel_size);
    assert_eq!(layout.dims, l.dims.to_vec());
    assert_eq!(layout.patch_count as usize, l.len());
    assert_eq!(layout.voxels.len(), 3 * l.len());
    assert_eq!(layout.faces.len(), l.len());
    for (i, p) in l.patches.iter().enumerate() {
        assert_eq!(&layout.voxels[3 * i..3 * i + 3], &p.voxel);
        assert_eq!(layout.faces[i], i32::from(p.face.code()));
        assert!(proto::Face::try_from(layout.faces[i]).is_ok());
    }
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn many_viewers_end_on_the_last_version_in_order() {
    let server = TestServer::start().await;
    let mut writer = server.client().await;
    let (id, v1) = create_session(&mut writer, vec![point(1.0)]).await;
    assert_eq!(v1, 1);
    // Each viewer on its own connection; the clients live as long as their streams.
    let mut clients = Vec::new();
    let mut viewers = Vec::new();
    for _ in 0..5 {
        let mut c = server.client().await;
        viewers.push(subscribe(&mut c, &id).await);
        clients.push(c);
    }
    // A burst: each call returns at once, the frames follow.
    const UPDATES: u64 = 30;
    let mut last = v1;
    for k in 0..UPDATES {
        let r = writer
            .set_lights(proto::SetLightsRequest {
                session_id: id.clone(),
                lights: vec![point(2.0 + k as f32)],
                token: String::new(),
            })
            .await
            .expect("set lights")
            .into_inner();
        assert!(r.changed);
        assert_eq!(r.lights_version, last + 1);
        last = r.lights_version;
    }
    let tasks: Vec<_> = viewers
        .into_iter()
        .map(|mut s| tokio::spawn(async move { read_until(&mut s, last).await }))
        .collect();
    let mut frames_seen = Vec::new();
    for t in tasks {
        let seen = t.await.expect("viewer");
        assert_eq!(seen.last().map(|s| s.1), Some(last));
        frames_seen.push(seen.len());
    }
    // Setting identical lights changes nothing: same version, no new frame.
    let r = writer
        .set_lights(proto::SetLightsRequest {
            session_id: id.clone(),
            lights: vec![point(2.0 + (UPDATES - 1) as f32)],
            token: String::new(),
        })
        .await
        .expect("set lights")
        .into_inner();
    assert_eq!((r.lights_version, r.changed), (last, false));
    let mut late_client = server.client().await;
    let mut late = subscribe(&mut late_client, &id).await;
    let newest = late
        .message()
        .await
        .expect("frame")
        .expect("a frame at once");
    assert_eq!(newest.lights_version, last);
    assert!(
        tokio::time::timeout(Duration::from_millis(300), late.message())
            .await
            .is_err(),
        "a frame arrived though the lights did not change"
    );
    eprintln!(
        "{UPDATES} updates: frames solved {} (batched/coalesced), frames seen per viewer {frames_seen:?}",
        newest.sequence
    );
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stalled_viewer_does_not_delay_the_others() {
    let server = TestServer::start().await;
    let mut writer = server.client().await;
    let (id, _) = create_session(&mut writer, vec![point(1.0)]).await;
    // Subscribed and never read while the updates run: its connection's flow-control windows
    // fill and the server cannot send it more.
    // Its HTTP/2 windows are small (16 KiB: a dozen frames), so the server soon has to stop
    // sending to it, as to a viewer on a slow link.
    let small_windows = Channel::from_shared(format!("http://{}", server.addr))
        .expect("uri")
        .initial_stream_window_size(Some(16 * 1024))
        .initial_connection_window_size(Some(16 * 1024))
        .connect()
        .await
        .expect("connect");
    let mut clients = [
        BounceClient::new(small_windows),
        server.client().await,
        server.client().await,
    ];
    let mut stalled = subscribe(&mut clients[0], &id).await;
    let mut readers = Vec::new();
    for c in &mut clients[1..] {
        readers.push(subscribe(c, &id).await);
    }
    // More frame bytes than the HTTP/2 windows hold (300 patches: 1.2 kB a frame), with a frame
    // solved between updates so that the server really tries to send each one.
    let mut last = 0;
    let mut readers_time = Duration::ZERO;
    for round in 0..12 {
        for k in 0..20 {
            let r = writer
                .set_lights(proto::SetLightsRequest {
                    session_id: id.clone(),
                    lights: vec![point(1.0 + (round * 20 + k) as f32)],
                    token: String::new(),
                })
                .await
                .expect("set lights")
                .into_inner();
            last = r.lights_version;
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
        let start = Instant::now();
        for r in &mut readers {
            read_until(r, last).await;
        }
        readers_time = readers_time.max(start.elapsed());
    }
    // The stalled viewer, read at last: in order, it ends on the newest version, having
    // skipped what it could not take.
    let seen = read_until(&mut stalled, last).await;
    assert_eq!(seen.last().map(|s| s.1), Some(last));
    assert!(
        (seen.len() as u64) < last,
        "the stalled viewer received every one of {last} versions: nothing was skipped"
    );
    eprintln!(
        "{last} versions; the stalled viewer got {} frames; slowest catch-up of the readers {:.1} ms",
        seen.len(),
        readers_time.as_secs_f64() * 1e3
    );
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_input_is_refused_naming_the_field_and_the_server_keeps_serving() {
    let server = TestServer::start().await;
    let mut c = server.client().await;
    let (id, _) = create_session(&mut c, vec![point(1.0)]).await;
    let set = |lights: Vec<PbLight>| proto::SetLightsRequest {
        session_id: id.clone(),
        lights,
        token: String::new(),
    };

    assert_status(
        c.set_lights(set(vec![point(1.0), point(f32::NAN)])).await,
        Code::InvalidArgument,
        "lights[1].intensity: must be finite",
    );
    let mut area = point(1.0);
    area.r#type = "area".into();
    assert_status(
        c.set_lights(set(vec![area.clone()])).await,
        Code::InvalidArgument,
        "lights[0].type: unknown light type \"area\"",
    );
    let mut negative = point(1.0);
    negative.color = vec![1.0, -1.0, 0.0];
    assert_status(
        c.set_lights(set(vec![negative])).await,
        Code::InvalidArgument,
        "lights[0].color",
    );
    assert_status(
        c.set_lights(set(vec![point(1.0); 257])).await,
        Code::InvalidArgument,
        "lights: 257 lights, more than the 256",
    );
    assert_status(
        c.create_session(proto::CreateSessionRequest {
            scene: SCENE.into(),
            lights: vec![area.clone()],
        })
        .await,
        Code::InvalidArgument,
        "lights[0].type",
    );
    assert_status(
        c.relight_once(proto::RelightOnceRequest {
            scene: SCENE.into(),
            lights: vec![point(f32::INFINITY)],
        })
        .await,
        Code::InvalidArgument,
        "lights[0].intensity",
    );
    // An emissive change this scene has no material for, on every way lights arrive: refused
    // before anything is stored or solved, naming what the scene has (the box emits nothing).
    let lamp = PbLight {
        r#type: "emissive".into(),
        material: Some("Lamp".into()),
        strength: Some(2.0),
        ..Default::default()
    };
    let none = "lights[1].material: the scene has no emissive material 'Lamp' (it has none)";
    assert_status(
        c.set_lights(set(vec![point(1.0), lamp.clone()])).await,
        Code::InvalidArgument,
        none,
    );
    assert_status(
        c.create_session(proto::CreateSessionRequest {
            scene: SCENE.into(),
            lights: vec![point(1.0), lamp.clone()],
        })
        .await,
        Code::InvalidArgument,
        none,
    );
    assert_status(
        c.relight_once(proto::RelightOnceRequest {
            scene: SCENE.into(),
            lights: vec![point(1.0), lamp],
        })
        .await,
        Code::InvalidArgument,
        none,
    );
    // Unknown names.
    assert_status(
        c.create_session(proto::CreateSessionRequest {
            scene: "nope".into(),
            lights: vec![],
        })
        .await,
        Code::NotFound,
        "unknown scene \"nope\"",
    );
    assert_status(
        c.get_layout(proto::GetLayoutRequest {
            scene: "nope".into(),
        })
        .await,
        Code::NotFound,
        "unknown scene",
    );
    assert_status(
        c.relight_once(proto::RelightOnceRequest {
            scene: "nope".into(),
            lights: vec![],
        })
        .await,
        Code::NotFound,
        "unknown scene",
    );
    assert_status(
        c.set_lights(proto::SetLightsRequest {
            session_id: "nope".into(),
            lights: vec![point(1.0)],
            token: String::new(),
        })
        .await,
        Code::NotFound,
        "unknown session \"nope\"",
    );
    assert_status(
        c.subscribe(proto::SubscribeRequest {
            session_id: "nope".into(),
        })
        .await,
        Code::NotFound,
        "unknown session",
    );
    // A refused change left the session as it was, and it still takes good ones.
    let r = c
        .set_lights(set(vec![point(5.0)]))
        .await
        .expect("still serving")
        .into_inner();
    assert_eq!((r.lights_version, r.changed), (2, true));
    let mut s = subscribe(&mut c, &id).await;
    read_until(&mut s, 2).await;
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn relight_once_matches_the_engine_within_rgb9e5() {
    let server = TestServer::start().await;
    let mut c = server.client().await;
    let lights = vec![
        point(3.0),
        PbLight {
            r#type: "spot".into(),
            position: vec![0.0, 1.9, 0.0],
            direction: vec![0.1, -1.0, 0.0],
            intensity: Some(20.0),
            outer_cone_angle: Some(0.8),
            ..Default::default()
        },
    ];
    let frame = c
        .relight_once(proto::RelightOnceRequest {
            scene: SCENE.into(),
            lights: lights.clone(),
        })
        .await
        .expect("relight once")
        .into_inner();
    let got = Frame::parse(frame.data).expect("frame").irradiance();

    let set = LightSet {
        lights: vec![
            Light::Point {
                position: [0.0, 1.0, 0.0],
                color: [1.0, 0.9, 0.8],
                intensity: 3.0,
                range: None,
                name: None,
            },
            Light::Spot {
                position: [0.0, 1.9, 0.0],
                direction: [0.1, -1.0, 0.0],
                color: [1.0; 3],
                intensity: 20.0,
                range: None,
                inner_cone_angle: 0.0,
                outer_cone_angle: 0.8,
                name: None,
            },
        ],
    };
    assert_eq!(bounce_server::lights::light_set(&lights), Ok(set.clone()));
    let engine = Engine::new(EngineChoice::Cpu).expect("cpu engine");
    let scene = engine.load(&baked()).expect("load");
    let want = engine
        .relight(&scene, &[set])
        .expect("relight")
        .remove(0)
        .indirect;
    assert_eq!(got.len(), want.len());
    let mut worst = 0.0f64;
    for (g, w) in got.iter().zip(&want) {
        let max = w.iter().fold(0.0f64, |m, &x| m.max(f64::from(x)));
        // RGB9E5's bound, and a hair for summation order.
        let bound = max / 511.0 + 2f64.powi(-25) + 1e-5 * max;
        for k in 0..3 {
            let err = (f64::from(g[k]) - f64::from(w[k])).abs();
            assert!(err <= bound, "{g:?} vs {w:?}");
            if max > 0.0 {
                worst = worst.max(err / max);
            }
        }
    }
    assert!(want.iter().any(|w| w[0] > 0.0), "the lights lit nothing");
    eprintln!("RelightOnce vs Engine::relight: worst error {worst:.2e} of the patch's max");
    server.stop().await;
}

/// A scene with probes: the layout says where they are, and every frame carries their light
/// beside the patches' (the same sequence and version), as the engine computes it within
/// RGB9E5's step.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_carry_probe_light_beside_the_patches() {
    let server = TestServer::start().await;
    let mut c = server.client().await;
    let probes = baked().probes.expect("the test scene has probes");
    let layout = c
        .get_layout(proto::GetLayoutRequest {
            scene: SCENE.into(),
        })
        .await
        .expect("layout")
        .into_inner();
    let flat: Vec<f32> = probes.positions.iter().flatten().copied().collect();
    assert_eq!(layout.probe_positions, flat);

    let (id, version) = create_session(&mut c, vec![point(3.0)]).await;
    let mut stream = subscribe(&mut c, &id).await;
    let frame = frame_answering(&mut stream, version).await;
    let probe_frame = Frame::parse_probes(frame.probes.clone()).expect("probe frame");
    assert_eq!(probe_frame.header.sequence, frame.sequence);
    assert_eq!(probe_frame.header.lights_version, frame.lights_version);
    let got = probe_frame.irradiance();
    assert_eq!(got.len(), 6 * probes.len());

    let engine = Engine::new(EngineChoice::Cpu).expect("cpu engine");
    let scene = engine.load(&baked()).expect("load");
    let set = bounce_server::lights::light_set(&[point(3.0)]).expect("lights");
    let want = engine
        .relight(&scene, &[set])
        .expect("relight")
        .remove(0)
        .probes;
    assert!(want.iter().any(|w| w[1] > 0.0), "the probes saw no light");
    assert_within_rgb9e5_step(&got, &want);
    server.stop().await;
}

/// Under a sky a frame carries the sky's direct light with the bounces: a viewer draws only the
/// punctual lights itself. The frame is the engine's `streamed()` (E_ind + the sky's share of
/// direct light) within RGB9E5's step, and brighter than E_ind alone where the sky is seen.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn under_a_sky_frames_carry_its_direct_light() {
    let server = TestServer::start().await;
    let mut c = server.client().await;
    let sky = PbLight {
        r#type: "sky".into(),
        color: vec![0.5, 0.6, 0.8],
        ..Default::default()
    };
    let lights = vec![point(3.0), sky];
    let (id, version) = create_session(&mut c, lights.clone()).await;
    let mut stream = subscribe(&mut c, &id).await;
    let frame = frame_answering(&mut stream, version).await;
    let got = Frame::parse(frame.data.clone())
        .expect("frame")
        .irradiance();

    let engine = Engine::new(EngineChoice::Cpu).expect("cpu engine");
    let scene = engine.load(&baked()).expect("load");
    let set = bounce_server::lights::light_set(&lights).expect("lights");
    let lit = engine.relight(&scene, &[set]).expect("relight").remove(0);
    assert_eq!(lit.sky.len(), got.len(), "the test scene has a sky view");
    assert_within_rgb9e5_step(&got, &lit.streamed());
    // Where the sky is seen, the frame is more than the bounces by the sky's direct light.
    let lifted = got
        .iter()
        .zip(&lit.indirect)
        .zip(&lit.sky)
        .filter(|((g, i), k)| k[2] > 0.1 * i[2] && g[2] > i[2] * 1.05)
        .count();
    assert!(
        lifted * 10 > got.len(),
        "{lifted} of {} patches carry the sky's direct light",
        got.len()
    );
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn relight_stream_takes_lights_and_returns_frames() {
    let server = TestServer::start().await;
    let mut c = server.client().await;
    let (tx, rx) = tokio::sync::mpsc::channel(4);
    tx.send(proto::RelightRequest {
        scene: SCENE.into(),
        set_lights: true,
        lights: vec![point(2.0)],
        ..Default::default()
    })
    .await
    .expect("send");
    let mut frames = c
        .relight(tokio_stream::wrappers::ReceiverStream::new(rx))
        .await
        .expect("relight")
        .into_inner();
    let first = read_until(&mut frames, 1).await;
    assert_eq!(first.last(), Some(&(1, 1)));
    tx.send(proto::RelightRequest {
        set_lights: true,
        lights: vec![point(4.0)],
        ..Default::default()
    })
    .await
    .expect("send");
    let second = read_until(&mut frames, 2).await;
    assert_eq!(second.last(), Some(&(2, 2)));
    // A bad message ends the stream with its status.
    tx.send(proto::RelightRequest {
        set_lights: true,
        lights: vec![point(-1.0)],
        ..Default::default()
    })
    .await
    .expect("send");
    let end = tokio::time::timeout(PATIENCE, frames.message())
        .await
        .expect("no answer");
    assert_status(end, Code::InvalidArgument, "lights[0].intensity");
    // A first message naming neither a session nor a scene.
    let (tx, rx) = tokio::sync::mpsc::channel(1);
    tx.send(proto::RelightRequest::default())
        .await
        .expect("send");
    assert_status(
        c.relight(tokio_stream::wrappers::ReceiverStream::new(rx))
            .await
            .map(|_| ()),
        Code::InvalidArgument,
        "session_id, scene",
    );
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn health_and_reflection_answer() {
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::health_client::HealthClient;
    use tonic_reflection::pb::v1::ServerReflectionRequest;
    use tonic_reflection::pb::v1::server_reflection_client::ServerReflectionClient;
    use tonic_reflection::pb::v1::server_reflection_request::MessageRequest;
    use tonic_reflection::pb::v1::server_reflection_response::MessageResponse;

    let server = TestServer::start().await;
    let mut health = HealthClient::new(server.channel().await);
    for service in ["", "bounce.v1.Bounce"] {
        let r = health
            .check(tonic_health::pb::HealthCheckRequest {
                service: service.into(),
            })
            .await
            .expect("health")
            .into_inner();
        assert_eq!(r.status(), ServingStatus::Serving, "{service:?}");
    }

    let mut reflection = ServerReflectionClient::new(server.channel().await);
    let request = ServerReflectionRequest {
        host: String::new(),
        message_request: Some(MessageRequest::ListServices(String::new())),
    };
    let mut answers = reflection
        .server_reflection_info(tokio_stream::iter([request]))
        .await
        .expect("reflection")
        .into_inner();
    let answer = answers.message().await.expect("answer").expect("one");
    let Some(MessageResponse::ListServicesResponse(list)) = answer.message_response else {
        panic!("not a service list: {answer:?}");
    };
    let names: Vec<_> = list.service.iter().map(|s| s.name.as_str()).collect();
    assert!(names.contains(&"bounce.v1.Bounce"), "{names:?}");
    assert!(names.contains(&"grpc.health.v1.Health"), "{names:?}");
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_ends_open_streams() {
    let server = TestServer::start().await;
    let mut c = server.client().await;
    let (id, v) = create_session(&mut c, vec![point(1.0)]).await;
    let mut s = subscribe(&mut c, &id).await;
    read_until(&mut s, v).await;
    let reader = tokio::spawn(async move {
        // After the newest frame, the stream's end: UNAVAILABLE, so a client can tell a
        // shutdown from a normal end (which would be OK).
        loop {
            match s.message().await {
                Ok(Some(_)) => continue,
                Ok(None) => return None,
                Err(status) => return Some(status),
            }
        }
    });
    server.stop().await;
    let end = tokio::time::timeout(PATIENCE, reader)
        .await
        .expect("the stream outlived the server")
        .expect("join");
    let status = end.expect("the stream ended with OK, as a normal end would");
    assert_eq!(status.code(), Code::Unavailable, "{status:?}");
}

/// Bytes sent as they are: a client that writes a broken message.
#[derive(Default, Clone)]
struct Raw;

struct RawEncoder;
struct RawDecoder;

impl tonic::codec::Codec for Raw {
    type Encode = Vec<u8>;
    type Decode = Vec<u8>;
    type Encoder = RawEncoder;
    type Decoder = RawDecoder;
    fn encoder(&mut self) -> RawEncoder {
        RawEncoder
    }
    fn decoder(&mut self) -> RawDecoder {
        RawDecoder
    }
}

impl tonic::codec::Encoder for RawEncoder {
    type Item = Vec<u8>;
    type Error = Status;
    fn encode(
        &mut self,
        item: Vec<u8>,
        buf: &mut tonic::codec::EncodeBuf<'_>,
    ) -> Result<(), Status> {
        bytes::BufMut::put_slice(buf, &item);
        Ok(())
    }
}

impl tonic::codec::Decoder for RawDecoder {
    type Item = Vec<u8>;
    type Error = Status;
    fn decode(&mut self, buf: &mut tonic::codec::DecodeBuf<'_>) -> Result<Option<Vec<u8>>, Status> {
        let n = bytes::Buf::remaining(buf);
        Ok(Some(bytes::Buf::copy_to_bytes(buf, n).to_vec()))
    }
}

/// A request body that does not decode is the client's error: INVALID_ARGUMENT, not INTERNAL
/// (prost's code, which would page an operator for a client's bug). One over the size limit is
/// OUT_OF_RANGE, tonic's check before decoding, as the README says.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn broken_and_oversized_messages_are_the_clients_errors() {
    let server = TestServer::start().await;
    let mut grpc = tonic::client::Grpc::new(server.channel().await);
    let call = |body: Vec<u8>| {
        let mut grpc = grpc.clone();
        async move {
            grpc.ready().await.expect("ready");
            grpc.unary::<Vec<u8>, Vec<u8>, Raw>(
                tonic::Request::new(body),
                "/bounce.v1.Bounce/GetLayout".parse().expect("path"),
                Raw,
            )
            .await
        }
    };
    // Field 1 (scene, a string) claims 100 bytes and has 2.
    let refused = call(vec![0x0a, 100, b'a', b'b']).await.expect_err("broken");
    assert_eq!(refused.code(), Code::InvalidArgument, "{refused:?}");
    assert!(refused.message().contains("does not decode"), "{refused:?}");
    let refused = call(vec![0x0a; 2 << 20]).await.expect_err("oversized");
    assert_eq!(refused.code(), Code::OutOfRange, "{refused:?}");
    // A well-formed call still works on the same channel.
    grpc.ready().await.expect("ready");
    server.stop().await;
}
