//! One running server: the gRPC and HTTP front ends over one hub, started together and stopped
//! together. `bounce serve`, `bounce bench serve` and the tests all run a server through here, so
//! what "the server stops" means is written once.

use std::future::Future;

use tokio::net::TcpListener;
use tokio::sync::watch;

use crate::error::ServerError;
use crate::grpc::serve_grpc;
use crate::http::serve_http;
use crate::hub::Hub;

/// Where each front end accepts connections; a front end without a listener is not served.
#[derive(Debug, Default)]
pub struct Listeners {
    pub grpc: Option<TcpListener>,
    pub http: Option<TcpListener>,
}

impl Listeners {
    /// Both front ends, as `bounce serve` has.
    pub fn both(grpc: TcpListener, http: TcpListener) -> Listeners {
        Listeners {
            grpc: Some(grpc),
            http: Some(http),
        }
    }

    pub fn grpc_only(grpc: TcpListener) -> Listeners {
        Listeners {
            grpc: Some(grpc),
            http: None,
        }
    }

    pub fn http_only(http: TcpListener) -> Listeners {
        Listeners {
            grpc: None,
            http: Some(http),
        }
    }
}

/// Serves `hub` on `listeners` until `shutdown` resolves or either front end ends; either way
/// both stop: health and readiness turn to not serving, the hub shuts down (every frame stream
/// ends, every WebSocket closes with 1001), in-flight calls finish, and this returns. A front end
/// that ends on an error stops the other too, so a server is never left half up; the error is
/// returned (gRPC's first, if both failed).
pub async fn run(
    hub: Hub,
    listeners: Listeners,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), ServerError> {
    let stop = watch::Sender::new(false);
    let stopped = |mut rx: watch::Receiver<bool>| async move {
        let _ = rx.wait_for(|&s| s).await;
    };
    let signal = async {
        tokio::select! {
            () = shutdown => {
                stop.send_replace(true);
            }
            () = stopped(stop.subscribe()) => {}
        }
    };
    let grpc = async {
        let Some(listener) = listeners.grpc else {
            return Ok(());
        };
        let served = serve_grpc(hub.clone(), listener, stopped(stop.subscribe())).await;
        stop.send_replace(true);
        served
    };
    let http = async {
        let Some(listener) = listeners.http else {
            return Ok(());
        };
        let served = serve_http(hub.clone(), listener, stopped(stop.subscribe())).await;
        stop.send_replace(true);
        served
    };
    let ((), grpc, http) = tokio::join!(signal, grpc, http);
    // With no front end at all, nothing else shuts the hub down; a second shutdown is a no-op.
    let _ = tokio::task::spawn_blocking(move || hub.shutdown()).await;
    grpc.and(http)
}
