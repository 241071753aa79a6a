//! The gRPC front end over the [`Hub`]: the bounce service ([`service`]), standard health and
//! reflection, graceful shutdown that ends every frame stream.

mod service;

pub use service::BounceService;

use std::future::Future;
use std::sync::Arc;

use tokio::net::TcpListener;
use tokio_stream::StreamExt as _;
use tokio_stream::wrappers::TcpListenerStream;
use tonic::transport::Server;
use tracing::info;

use crate::error::ServerError;
use crate::hub::Hub;
use crate::limits::ConnectionLimit;
use crate::metrics::Transport;
use crate::proto;
use crate::proto::bounce_server::BounceServer;
use bounce_wire::limits::MAX_REQUEST_BYTES;

/// Calls in flight on one connection (streams included).
pub const MAX_CALLS_PER_CONNECTION: usize = 256;

/// Serves `hub` on `listener` until `shutdown` resolves; then health turns NOT_SERVING, the hub
/// shuts down (every frame stream ends), and in-flight calls finish.
pub async fn serve_grpc(
    hub: Hub,
    listener: TcpListener,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), ServerError> {
    let (health, health_service) = tonic_health::server::health_reporter();
    health.set_serving::<BounceServer<BounceService>>().await;
    let reflection = || {
        tonic_reflection::server::Builder::configure()
            .register_encoded_file_descriptor_set(proto::FILE_DESCRIPTOR_SET)
            .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
    };
    let reflection_v1 = reflection()
        .build_v1()
        .map_err(|e| ServerError::Reflection(e.to_string()))?;
    // grpcurl and many tools still ask v1alpha.
    let reflection_v1alpha = reflection()
        .build_v1alpha()
        .map_err(|e| ServerError::Reflection(e.to_string()))?;
    let bounce = BounceServer::new(BounceService::new(hub.clone()))
        .max_decoding_message_size(MAX_REQUEST_BYTES);

    // Frames are small and latency matters: no Nagle delay on accepted connections. Past the
    // connection limit a connection is dropped (closed) at once.
    let limit = ConnectionLimit::new(
        hub.max_connections(),
        Transport::Grpc,
        Arc::clone(hub.metrics()),
    )
    .with_first_byte_timeout(hub.first_byte_timeout())
    .with_per_ip(hub.max_connections_per_ip());
    let incoming = TcpListenerStream::new(listener).filter_map(move |s| match s {
        Ok(s) => {
            let _ = s.set_nodelay(true);
            match s.peer_addr() {
                Ok(peer) => limit.admit_from(s, peer.ip()).map(Ok),
                // Already gone: dropping it is all there is to do.
                Err(_) => None,
            }
        }
        Err(e) => Some(Err(e)),
    });
    let stopping = async move {
        shutdown.await;
        info!("shutting down");
        health
            .set_not_serving::<BounceServer<BounceService>>()
            .await;
        // The worker may be mid-batch: wait for it off the runtime's threads.
        let _ = tokio::task::spawn_blocking(move || hub.shutdown()).await;
    };
    Server::builder()
        // One client's streams cannot take every worker: each connection gets this many calls
        // in flight (a viewer's stream is one).
        .concurrency_limit_per_connection(MAX_CALLS_PER_CONNECTION)
        .add_service(health_service)
        .add_service(reflection_v1)
        .add_service(reflection_v1alpha)
        .add_service(bounce)
        .serve_with_incoming_shutdown(incoming, stopping)
        .await?;
    Ok(())
}
