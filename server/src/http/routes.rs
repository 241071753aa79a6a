//! The JSON routes: health, readiness, metrics, scenes, layouts, models and sessions (the table
//! in [`super`]).

use axum::Extension;
use axum::Json;
use axum::extract::rejection::BytesRejection;
use axum::extract::{ConnectInfo, Path, Query, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use bounce_core::emitter::{materials_of, nodes_of};
use bounce_core::light::LightSet;
use bytes::Bytes;
use serde::{Deserialize, Serialize};

use super::access::Token;
use super::error::{ApiError, ErrorCode};
use super::state::{AppState, Peer};
use crate::cache;
use crate::error::ServerError;
use crate::metrics;
use crate::proto;

/// `lights` (the array of a `{"lights": [...]}` document) read and validated as
/// [`LightSet::from_json`] does, so errors name the light and field (`lights[2].intensity`).
fn light_set(lights: serde_json::Value) -> Result<LightSet, ServerError> {
    Ok(bounce_wire::text::light_set(lights)?)
}

fn body_str(body: &Bytes) -> Result<&str, ServerError> {
    std::str::from_utf8(body)
        .map_err(|e| ServerError::Invalid(format!("request body: not UTF-8 ({e})")))
}

pub(super) async fn readyz(State(state): State<AppState>) -> (StatusCode, &'static str) {
    if state.hub.is_ready() {
        (StatusCode::OK, "ready")
    } else {
        (StatusCode::SERVICE_UNAVAILABLE, "not ready")
    }
}

pub(super) async fn metrics(State(state): State<AppState>) -> impl IntoResponse {
    (
        [(header::CONTENT_TYPE, metrics::CONTENT_TYPE)],
        state.hub.metrics().encode(),
    )
}

#[derive(Serialize)]
pub(super) struct SceneList {
    engine: String,
    /// Whether creating sessions and changing lights need the server's token.
    writes_need_token: bool,
    /// Whether reads need a token (only a client that presented one sees this answer).
    reads_need_token: bool,
    scenes: Vec<SceneEntry>,
}

#[derive(Serialize)]
pub(super) struct SceneEntry {
    name: String,
    patch_count: usize,
    codec: String,
    /// Whether `GET /v1/scenes/{name}/model` has a model to give.
    has_model: bool,
    /// Why a GPU engine runs part of this scene on the CPU (a matrix or a triangle set over what
    /// the device holds), or null.
    fallback: Option<String>,
    /// Whether a sky lights the scene: false for a file baked before the sky view (bake again).
    sky_view: bool,
    /// The emissive materials a light set may change (`{"type": "emissive", "material": ...}`);
    /// empty for a scene without any or a file baked before them (bake again).
    emitters: Vec<String>,
    /// The nodes that place them (`{"type": "emissive", "node": ...}`); empty for a file baked
    /// before emitters knew their nodes.
    emitter_nodes: Vec<String>,
}

pub(super) async fn list_scenes(State(state): State<AppState>) -> Json<SceneList> {
    let scenes = state
        .hub
        .scenes()
        .iter()
        .map(|s| SceneEntry {
            name: s.name.clone(),
            patch_count: s.layout.len(),
            codec: s.codec.clone(),
            has_model: s.model.is_some(),
            fallback: state.hub.scene_fallback(&s.name),
            sky_view: s.sky_view,
            emitters: s.emitters.as_deref().map(materials_of).unwrap_or_default(),
            emitter_nodes: s.emitters.as_deref().map(nodes_of).unwrap_or_default(),
        })
        .collect();
    Json(SceneList {
        engine: state.hub.engine(),
        writes_need_token: state.hub.has_token(),
        reads_need_token: state.hub.has_read_token(),
        scenes,
    })
}

/// The scene's model as one GLB: from its baked file, else from a glTF beside it.
pub(super) async fn model(
    State(state): State<AppState>,
    Path(name): Path<String>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let scene = state.hub.scene(&name)?;
    let Some(model) = &scene.model else {
        let file = |ext| {
            scene
                .path
                .with_extension(ext)
                .file_name()
                .map(|f| f.to_string_lossy().into_owned())
                .unwrap_or_default()
        };
        return Err(ApiError::new(
            ErrorCode::NotFound,
            format!(
                "scene {name:?} has no model: its baked file {} was made without one (an older \
                 bounce, or `bounce bake --no-model`). Bake the scene again with this bounce, \
                 which keeps the model, or put the glTF it was baked from beside it as {} or {} \
                 (a .gltf with its files beside it)",
                file("bounce"),
                file("glb"),
                file("gltf")
            ),
        ));
    };
    Ok(cache::respond(
        &headers,
        model.bytes.clone(),
        &model.etag,
        "model/gltf-binary",
    ))
}

/// The proto `Layout`, field for field.
#[derive(Serialize)]
pub(super) struct Layout {
    scene: String,
    origin: Vec<f32>,
    voxel_size: f32,
    dims: Vec<u32>,
    patch_count: u32,
    /// x, y, z of each patch's voxel, flat.
    voxels: Vec<u32>,
    /// Each patch's face code (0..5: +X, −X, +Y, −Y, +Z, −Z).
    faces: Vec<i32>,
    /// x, y, z of each irradiance probe, flat; empty without probes.
    probe_positions: Vec<f32>,
}

impl From<proto::Layout> for Layout {
    fn from(l: proto::Layout) -> Layout {
        Layout {
            scene: l.scene,
            origin: l.origin,
            voxel_size: l.voxel_size,
            dims: l.dims,
            patch_count: l.patch_count,
            voxels: l.voxels,
            faces: l.faces,
            probe_positions: l.probe_positions,
        }
    }
}

pub(super) async fn layout(
    State(state): State<AppState>,
    Path(name): Path<String>,
) -> Result<Json<Layout>, ApiError> {
    let scene = state.hub.scene(&name)?;
    Ok(Json(scene.wire_layout().into()))
}

/// Sessions a list gives when no `limit` is asked, and the most it gives.
const LIST_DEFAULT: usize = 100;
const LIST_MAX: usize = 1000;

#[derive(Deserialize)]
pub(super) struct ListQuery {
    scene: Option<String>,
    /// Read as text so that a bad value gets our message, not the extractor's.
    limit: Option<String>,
}

#[derive(Serialize)]
pub(super) struct SessionList {
    sessions: Vec<SessionEntry>,
}

#[derive(Serialize)]
pub(super) struct SessionEntry {
    session_id: String,
    scene: String,
    lights_version: u64,
    /// Open viewers: gRPC streams and WebSockets.
    viewers: usize,
}

pub(super) async fn list_sessions(
    State(state): State<AppState>,
    query: Result<Query<ListQuery>, axum::extract::rejection::QueryRejection>,
) -> Result<Json<SessionList>, ApiError> {
    let Query(q) = query.map_err(|r| ApiError::from_rejection(r.status(), r.body_text()))?;
    let limit = match q.limit.as_deref() {
        None => LIST_DEFAULT,
        Some(l) => l
            .trim()
            .parse::<usize>()
            .ok()
            .filter(|n| (1..=LIST_MAX).contains(n))
            .ok_or_else(|| {
                ServerError::Invalid(format!(
                    "limit {l:?}: give a whole number from 1 to {LIST_MAX} (default {LIST_DEFAULT})"
                ))
            })?,
    };
    let scene = q.scene.as_deref().filter(|s| !s.is_empty());
    let sessions = state
        .hub
        .list_sessions(scene, limit)?
        .iter()
        .map(|s| SessionEntry {
            session_id: s.id.clone(),
            scene: state.hub.scene_of(s),
            lights_version: s.lights_version(),
            viewers: s.viewers(),
        })
        .collect();
    Ok(Json(SessionList { sessions }))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct CreateSession {
    scene: String,
    /// Absent: no lights yet, as gRPC's empty list.
    #[serde(default)]
    lights: Option<serde_json::Value>,
}

#[derive(Serialize)]
pub(super) struct Created {
    session_id: String,
    lights_version: u64,
}

pub(super) async fn create_session(
    State(state): State<AppState>,
    connected: Option<Extension<ConnectInfo<Peer>>>,
    Token(token): Token,
    body: Result<Bytes, BytesRejection>,
) -> Result<Response, ApiError> {
    state.hub.authorize(token.as_deref())?;
    let body = body?;
    let request: CreateSession = serde_json::from_str(body_str(&body)?)
        .map_err(|e| ServerError::Invalid(format!("request body: {e}")))?;
    let lights = match request.lights {
        Some(l) => light_set(l)?,
        None => LightSet::default(),
    };
    let client = connected.map(|Extension(ConnectInfo(Peer(addr)))| addr.ip());
    let session = state
        .hub
        .create_session(&request.scene, lights, client)
        .await?;
    let location = format!("/v1/sessions/{}", session.id);
    let created = Created {
        session_id: session.id.clone(),
        lights_version: session.lights_version(),
    };
    Ok((
        StatusCode::CREATED,
        [(header::LOCATION, location)],
        Json(created),
    )
        .into_response())
}

#[derive(Serialize)]
pub(super) struct SessionState {
    session_id: String,
    scene: String,
    lights_version: u64,
    lights: Vec<bounce_core::light::Light>,
}

pub(super) async fn get_session(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<SessionState>, ApiError> {
    let session = state.hub.session(&id)?;
    Ok(Json(SessionState {
        session_id: session.id.clone(),
        scene: state.hub.scene_of(&session),
        lights_version: session.lights_version(),
        lights: session.lights().lights,
    }))
}

#[derive(Serialize)]
pub(super) struct LightsChanged {
    lights_version: u64,
    changed: bool,
}

pub(super) async fn set_lights(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Token(token): Token,
    body: Result<Bytes, BytesRejection>,
) -> Result<Json<LightsChanged>, ApiError> {
    state.hub.authorize(token.as_deref())?;
    // The session first: an unknown session is 404 whatever the lights hold.
    state.hub.session(&id)?;
    let body = body?;
    let lights = LightSet::from_json(body_str(&body)?).map_err(ServerError::from)?;
    let v = state.hub.set_lights(&id, lights).await?;
    Ok(Json(LightsChanged {
        lights_version: v.version,
        changed: v.changed,
    }))
}

/// The largest environment image `POST /v1/sky/sh` takes: an 8k × 4k Radiance file, run-length
/// encoded, is well under it; an OpenEXR of that size in f16 fits.
pub(super) const MAX_ENVIRONMENT_BYTES: usize = 64 << 20;

#[derive(Serialize)]
pub(super) struct SkySh {
    /// The 9 order-2 coefficients, `[r, g, b]` each, as a sky light's `sh` takes them.
    sh: Vec<[f32; 3]>,
    width: u32,
    height: u32,
}

/// An equirectangular HDR image (the body: Radiance `.hdr` or OpenEXR) projected to the order-2
/// SH a sky light takes (`bounce_core::environment`). A write like setting lights: it presents
/// the write token when the server has one, since decoding a large image is work done on the
/// server's cores (on the blocking pool, not the async workers).
pub(super) async fn sky_sh(
    State(state): State<AppState>,
    Token(token): Token,
    body: Result<Bytes, BytesRejection>,
) -> Result<Json<SkySh>, ApiError> {
    state.hub.authorize(token.as_deref())?;
    let body = body?;
    let env = tokio::task::spawn_blocking(move || bounce_core::environment::sh_from_image(&body))
        .await
        // Only a panic in the decoder ends the task early: the server goes on, this request
        // is answered as a failed one.
        .map_err(|_| ServerError::WorkerGone)?
        .map_err(|e| ServerError::Invalid(format!("the image: {e}")))?;
    Ok(Json(SkySh {
        sh: env.sh.to_vec(),
        width: env.width,
        height: env.height,
    }))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SunRequest {
    /// Towards the sun, +Y up, any length.
    direction: [f32; 3],
    #[serde(default = "typical_turbidity")]
    turbidity: f64,
    #[serde(default = "unit_scale")]
    scale: f64,
}

fn typical_turbidity() -> f64 {
    3.0
}

fn unit_scale() -> f64 {
    1.0
}

/// A sun and its clear sky (`bounce_core::sunsky`) as the two lights a session takes: a day's
/// sequence of these is a day-night cycle. Computed, not stored: no token is needed beyond a
/// read's.
pub(super) async fn sky_sun(
    body: Result<Bytes, BytesRejection>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let body = body?;
    let request: SunRequest = serde_json::from_str(body_str(&body)?)
        .map_err(|e| ServerError::Invalid(format!("request body: {e}")))?;
    let set = bounce_core::sunsky::sun_and_sky(request.direction, request.turbidity, request.scale)
        .map_err(|e| ServerError::Invalid(e.to_string()))?;
    Ok(Json(serde_json::json!({ "lights": set.lights })))
}
