//! The client over gRPC against a real server: layout, sessions, lights, frames into a volume,
//! refusals and connection failures.

use half::f16;

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_layout_is_the_baked_files() {
    let server = TestServer::start().await;
    let client = server.client().await;
    assert_eq!(client.scheme(), Scheme::Grpc);
    let layout = client.get_layout(SCENE).await.expect("layout");
    let baked = baked().layout;
    assert_eq!(layout.scene(), SCENE);
    assert_eq!(layout.origin().to_array(), baked.origin);
    assert_eq!(layout.voxel_size(), baked.voxel_size);
    assert_eq!(layout.dims().to_array(), baked.dims);
    assert_eq!(layout.patch_count(), baked.patches.len());
    for (got, want) in layout.patches().iter().zip(&baked.patches) {
        assert_eq!(got.voxel.to_array(), want.voxel);
        assert_eq!(got.face, want.face);
    }
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_fill_the_volume_and_follow_the_lights() {
    let server = TestServer::start().await;
    let client = server.client().await;
    let layout = client.get_layout(SCENE).await.expect("layout");
    let session = client
        .create_session(SCENE, &point(5.0))
        .await
        .expect("session");
    assert_eq!(session.lights_version, 1);
    let mut frames = client.subscribe(&session.id).await.expect("subscribe");
    let first = read_until(&mut frames, 1).await;
    assert_eq!(first.header.patch_count as usize, layout.patch_count());

    let mut volume = Volume::new(&layout).expect("volume");
    volume.apply(&first).expect("apply");
    assert_eq!(volume.frame(), Some(first.header));
    let irradiance = first.irradiance();
    assert!(irradiance.iter().any(|rgb| rgb[0] > 0.0), "a lit box");
    let covered: usize = Face::ALL
        .iter()
        .map(|&f| volume.texels(f).iter().filter(|t| t[3] == f16::ONE).count())
        .sum();
    assert_eq!(covered, layout.patch_count());
    for (patch, rgb) in layout.patches().iter().zip(&irradiance) {
        let want = rgb.map(|c| f16::from_f32(c).to_f32());
        let texel = volume.texel(patch.face, patch.voxel).expect("inside");
        assert_eq!(texel.map(f16::to_f32), [want[0], want[1], want[2], 1.0]);
        // At the voxel centre along the face's normal the filter reads this texel alone (up to
        // the rounding of the centre's world position back into texel coordinates).
        let centre = layout.voxel_center(patch.voxel);
        let got = volume.sample(centre, patch.face.normal());
        for k in 0..3 {
            assert!(
                (got[k] - want[k]).abs() <= 1e-5 * want[k].max(1e-3),
                "{patch:?}: {got:?} against {want:?}"
            );
        }
    }

    let change = client
        .set_lights(&session.id, &point(20.0))
        .await
        .expect("set lights");
    assert_eq!(
        change,
        LightsChange {
            lights_version: 2,
            changed: true
        }
    );
    let second = read_until(&mut frames, 2).await;
    assert_eq!(second.header.lights_version, 2);
    let brighter = second.irradiance();
    let sum = |v: &[[f32; 3]]| v.iter().map(|c| f64::from(c[0])).sum::<f64>();
    assert!(
        sum(&brighter) > 3.0 * sum(&irradiance),
        "4x the light, more light"
    );
    // The same lights again change nothing.
    let same = client
        .set_lights(&session.id, &point(20.0))
        .await
        .expect("set lights");
    assert_eq!(
        same,
        LightsChange {
            lights_version: 2,
            changed: false
        }
    );
    frames.close().await;
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn refusals_carry_the_servers_code_and_message() {
    let server = TestServer::start().await;
    let client = server.client().await;
    assert_refused(
        client.get_layout("no-such-scene").await,
        Refusal::NotFound,
        "no-such-scene",
    );
    assert_refused(
        client.create_session("no-such-scene", &point(1.0)).await,
        Refusal::NotFound,
        "no-such-scene",
    );
    assert_refused(
        client.create_session(SCENE, &point(-2.0)).await,
        Refusal::InvalidArgument,
        "lights[0].intensity",
    );
    assert_refused(
        client.set_lights("nobody", &point(1.0)).await,
        Refusal::NotFound,
        "nobody",
    );
    assert_refused(
        client.subscribe("nobody").await.map(|_| ()),
        Refusal::NotFound,
        "nobody",
    );
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn writes_present_the_token() {
    let mut config = config();
    config.token = Some("s3cret".into());
    let server = TestServer::start_with(config).await;
    let anonymous = server.client().await;
    assert_refused(
        anonymous.create_session(SCENE, &point(1.0)).await,
        Refusal::Unauthenticated,
        "token",
    );
    let writer = Client::connect(ClientConfig::new(server.grpc_url()).with_token("s3cret"))
        .await
        .expect("connect");
    let session = writer
        .create_session(SCENE, &point(1.0))
        .await
        .expect("with the token");
    writer
        .set_lights(&session.id, &point(2.0))
        .await
        .expect("with the token");
    // Viewers need no token.
    let mut frames = anonymous.subscribe(&session.id).await.expect("subscribe");
    read_until(&mut frames, 2).await;
    assert!(matches!(
        Client::connect(ClientConfig::new(server.grpc_url()).with_token("bad\ntoken")).await,
        Err(ClientError::InvalidToken)
    ));
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_subscription_ends_when_the_server_stops() {
    let server = TestServer::start().await;
    let client = server.client().await;
    let session = client
        .create_session(SCENE, &point(5.0))
        .await
        .expect("session");
    let mut frames = client.subscribe(&session.id).await.expect("subscribe");
    read_until(&mut frames, 1).await;
    server.stop().await;
    let end = tokio::time::timeout(PATIENCE, frames.next())
        .await
        .expect("the stream ends");
    match end {
        Ok(None) => {}
        Err(e) => assert!(e.is_transient(), "{e}"),
        Ok(Some(f)) => panic!("a frame after shutdown: {:?}", f.header),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn connection_failures_are_transient_and_bad_addresses_are_not() {
    // A port nothing listens on: bind one, then let it go.
    let port = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
        l.local_addr().expect("addr").port()
    };
    for url in [
        format!("http://127.0.0.1:{port}"),
        format!("ws://127.0.0.1:{port}"),
    ] {
        match Client::connect(url.as_str()).await {
            Err(e @ ClientError::Connect { .. }) => assert!(e.is_transient(), "{e}"),
            Err(e) => panic!("{url}: expected a connect error, got {e}"),
            Ok(_) => panic!("{url}: connected to nothing"),
        }
    }
    match Client::connect("grpc://127.0.0.1:1").await {
        Err(e @ ClientError::Url { .. }) => assert!(!e.is_transient()),
        Err(e) => panic!("expected a URL error, got {e}"),
        Ok(_) => panic!("connected with a bad scheme"),
    }
}
