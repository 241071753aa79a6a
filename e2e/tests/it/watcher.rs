//! The reconnecting watcher against real servers: it follows a session's lights, keeps its last
//! frame while the server is gone, and picks the session up again from a restarted server.

use tokio::sync::watch;

use crate::common::*;

async fn wait_for_state(
    state: &mut watch::Receiver<ConnectionState>,
    what: &str,
    mut want: impl FnMut(&ConnectionState) -> bool,
) -> ConnectionState {
    let waited = tokio::time::timeout(PATIENCE, state.wait_for(|s| want(s)))
        .await
        .map(|r| r.expect("watcher alive").clone());
    waited.unwrap_or_else(|_| panic!("never {what}: last {:?}", *state.borrow()))
}

/// Waits for a frame that answers `version` or later (the one held counts).
async fn wait_for_version(frames: &mut watch::Receiver<Option<Frame>>, version: u64) -> Frame {
    let frame = tokio::time::timeout(
        PATIENCE,
        frames.wait_for(|f| {
            f.as_ref()
                .is_some_and(|f| f.header.lights_version >= version)
        }),
    )
    .await
    .unwrap_or_else(|_| panic!("no frame for version {version}"))
    .expect("watcher alive");
    frame.clone().expect("a frame")
}

/// Waits for the next frame the watcher delivers after the last one seen on `frames`.
async fn next_frame(frames: &mut watch::Receiver<Option<Frame>>) -> Frame {
    tokio::time::timeout(PATIENCE, frames.changed())
        .await
        .expect("a new frame in time")
        .expect("watcher alive");
    frames.borrow_and_update().clone().expect("a frame")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_watcher_follows_light_changes_in_order() {
    let server = TestServer::start().await;
    let client = server.client().await;
    let session = client
        .create_session(SCENE, &point(1.0))
        .await
        .expect("session");
    let watcher = Watcher::spawn(server.grpc_url(), session.id.clone());
    assert_eq!(watcher.session(), session.id);
    let mut frames = watcher.frames();
    let mut state = watcher.state();
    wait_for_version(&mut frames, 1).await;
    wait_for_state(&mut state, "live", |s| {
        matches!(s, ConnectionState::Live { .. })
    })
    .await;

    // A burst of changes: the watcher may skip some, but ends on the last and never goes back.
    let seen = tokio::spawn({
        let mut frames = watcher.frames();
        async move {
            let mut seen = Vec::new();
            while frames.changed().await.is_ok() {
                let header = frames.borrow_and_update().as_ref().map(|f| f.header);
                if let Some(h) = header {
                    seen.push((h.lights_version, h.sequence));
                    if h.lights_version == 6 {
                        break;
                    }
                }
            }
            seen
        }
    });
    for k in 2..=6u8 {
        let change = client
            .set_lights(&session.id, &point(f32::from(k)))
            .await
            .expect("set lights");
        assert_eq!(change.lights_version, u64::from(k));
    }
    let seen = tokio::time::timeout(PATIENCE, seen)
        .await
        .expect("the last version in time")
        .expect("join");
    assert_eq!(seen.last().map(|s| s.0), Some(6), "{seen:?}");
    assert!(seen.windows(2).all(|w| w[1] > w[0]), "{seen:?}");
    assert_eq!(watcher.latest().map(|f| f.header.lights_version), Some(6));
    drop(watcher);
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_watcher_keeps_the_last_frame_and_reconnects_to_a_restarted_server() {
    let data = tempfile::tempdir().expect("tempdir");
    let durable = || {
        let mut c = config();
        c.data_dir = Some(data.path().to_path_buf());
        c
    };
    let first = TestServer::start_with(durable()).await;
    let addr = first.addr;
    let url = first.grpc_url();
    let session = first
        .client()
        .await
        .create_session(SCENE, &point(5.0))
        .await
        .expect("session");
    let watcher = Watcher::spawn(url.as_str(), session.id.clone());
    let mut frames = watcher.frames();
    let mut state = watcher.state();
    let before = wait_for_version(&mut frames, 1).await;
    frames.borrow_and_update();
    wait_for_state(&mut state, "live", |s| {
        matches!(s, ConnectionState::Live { .. })
    })
    .await;

    first.stop().await;
    let down = wait_for_state(&mut state, "disconnected", |s| {
        matches!(s, ConnectionState::Disconnected { .. })
    })
    .await;
    let ConnectionState::Disconnected {
        retry_in, error, ..
    } = &down
    else {
        unreachable!()
    };
    assert!(*retry_in <= Duration::from_secs(5), "{down:?}");
    assert!(!error.is_empty());
    // Down for a while (several retries fail): the last frame stays.
    tokio::time::sleep(Duration::from_millis(700)).await;
    assert!(matches!(
        *state.borrow(),
        ConnectionState::Disconnected { .. } | ConnectionState::Connecting { .. }
    ));
    assert_eq!(watcher.latest(), Some(before.clone()));
    assert!(!frames.has_changed().expect("watcher alive"));

    // The same data on the same port: the session comes back and the watcher finds it alone.
    let second = TestServer::start_on(durable(), addr).await;
    let again = next_frame(&mut frames).await;
    wait_for_state(&mut state, "live again", |s| {
        matches!(s, ConnectionState::Live { .. })
    })
    .await;
    assert_eq!(again.header.lights_version, 1);
    // The new run counts its frames from 1; same lights, same matrix: the same irradiance.
    assert!(again.header.sequence <= before.header.sequence);
    assert_eq!(again.irradiance(), before.irradiance());

    // And it goes on following the session on the new server.
    let change = second
        .client()
        .await
        .set_lights(&session.id, &point(9.0))
        .await
        .expect("set lights");
    assert_eq!(change.lights_version, 2);
    let newer = wait_for_version(&mut frames, 2).await;
    assert_ne!(newer.irradiance(), before.irradiance());
    drop(watcher);
    second.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_unknown_session_is_reported_and_retried_slowly() {
    let server = TestServer::start().await;
    let watcher = Watcher::spawn(server.grpc_url(), "no-such-session");
    let mut state = watcher.state();
    let down = wait_for_state(&mut state, "disconnected", |s| {
        matches!(s, ConnectionState::Disconnected { .. })
    })
    .await;
    let ConnectionState::Disconnected {
        retry_in, error, ..
    } = down
    else {
        unreachable!()
    };
    assert!(error.contains("no-such-session"), "{error}");
    // Not a failure retrying fixes soon: the longest wait, not the first.
    assert!(retry_in >= Duration::from_millis(2500), "{retry_in:?}");
    assert!(watcher.latest().is_none());
    drop(watcher);
    server.stop().await;
}
