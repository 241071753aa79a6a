//! `bounce-e2e`: no library, only tests (`tests/it/`): the thin client (`bounce-client`) against
//! a real `bounce-server` on loopback, over gRPC and WebSocket, with a Cornell box baked for the
//! run. They live in their own crate so that the client's dependency graph, dev-dependencies
//! included, is the thin client's alone: no engine, faer, redb or axum.
