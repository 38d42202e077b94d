//! The live dashboard: one page (HTML, JS and CSS in `dashboard/index.html`, embedded in
//! the binary) and the JSON, image and event endpoints it reads. Jobs and workers come
//! from `/api/state`; `/api/events` (Server-Sent Events) says when a job's image changed,
//! and the page then loads `/api/jobs/ID/image.png` (the current merge, tone-mapped at
//! the page's exposure) and `/tiles` (each tile's progress, for the overlay). Actions are
//! POSTs that carry an `X-Tilefarm` header (a page of another site cannot add one).
//!
//! Who may see what is the gRPC API's rule: a token from `Authorization: Bearer …` or
//! the page's `tilefarm_token` cookie; a user sees and acts on their own jobs only.

use std::convert::Infallible;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use axum::Json;
use axum::extract::{Path, Query, State};
use axum::http::{HeaderMap, HeaderName, StatusCode, header};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{Html, IntoResponse, Response};
use proto::auth::{Caller, Role};
use serde::{Deserialize, Serialize};
use tracer::output::views::{View, view_png};

use super::app::App;
use crate::farm::job::ImageTiles;
use crate::farm::lifecycle::ImageError;
use crate::farm::state::JobChange;
use crate::farm::status::JobStatus;

const PAGE: &str = include_str!("dashboard/index.html");

/// How often the event stream looks for merged batches: well within the second the page
/// promises between a batch landing and its image.
const EVENT_POLL: Duration = Duration::from_millis(150);

pub(super) async fn page() -> Html<&'static str> {
    Html(PAGE)
}

/// Why a request is refused: its status and a line of text.
struct Refused(StatusCode, String);

impl IntoResponse for Refused {
    fn into_response(self) -> Response {
        (self.0, self.1).into_response()
    }
}

/// The caller, from the header or the cookie; or the refusal.
fn caller(app: &App, headers: &HeaderMap) -> Result<Caller, Refused> {
    let cookie = headers.get_all(header::COOKIE).iter().filter_map(|v| v.to_str().ok()).find_map(|c| {
        c.split(';').find_map(|kv| kv.trim().strip_prefix("tilefarm_token=").map(|t| format!("Bearer {t}")))
    });
    let bearer = headers.get(header::AUTHORIZATION).and_then(|v| v.to_str().ok()).map(str::to_string).or(cookie);
    app.access
        .identify(bearer.as_deref(), None)
        .map_err(|e| Refused(StatusCode::UNAUTHORIZED, format!("{}\n", e.message())))
        .and_then(|c| match c.role {
            Role::Worker => Err(Refused(StatusCode::FORBIDDEN, "a worker certificate has no dashboard\n".into())),
            _ => Ok(c),
        })
}

#[derive(Serialize)]
struct JobRow {
    id: String,
    name: String,
    owner: String,
    state: &'static str,
    paused: bool,
    priority: u32,
    width: u32,
    height: u32,
    units_done: u64,
    units_total: u64,
    samples_done: u64,
    samples_total: u64,
    samples_per_s: f64,
    submitted_unix_s: f64,
    error: String,
}

impl From<JobStatus> for JobRow {
    fn from(s: JobStatus) -> Self {
        Self {
            id: s.job_id,
            name: s.scene,
            owner: s.owner,
            state: s.state.name(),
            paused: s.paused,
            priority: s.priority,
            width: s.width,
            height: s.height,
            units_done: s.units_done,
            units_total: s.units_total,
            samples_done: s.samples_done,
            samples_total: s.samples_total,
            samples_per_s: s.samples_per_s,
            submitted_unix_s: s.submitted_unix_s,
            error: s.error,
        }
    }
}

#[derive(Serialize)]
struct WorkerRow {
    id: u64,
    host: String,
    threads: u32,
    units_held: usize,
    units_done: u64,
    last_seen_s: f64,
    quarantined: bool,
}

#[derive(Serialize)]
struct FarmState {
    jobs: Vec<JobRow>,
    workers: Vec<WorkerRow>,
}

pub(super) async fn state(State(app): State<App>, headers: HeaderMap) -> Response {
    let who = match caller(&app, &headers) {
        Ok(c) => c,
        Err(r) => return r.into_response(),
    };
    let farm = app.shared.farm();
    let now = Instant::now();
    let jobs = farm.statuses_of(now, |owner| who.may_touch(owner)).into_iter().map(JobRow::from).collect();
    // Which machines render is the operator's to know, not every user's.
    let admin = who.role == Role::Admin;
    let workers = farm
        .workers
        .values()
        .map(|w| WorkerRow {
            id: w.id,
            host: if admin { w.hostname.clone() } else { String::new() },
            threads: w.threads,
            units_held: farm.jobs.iter().map(|e| e.job.held_by(w.id)).sum(),
            units_done: w.units_done,
            last_seen_s: now.saturating_duration_since(w.last_seen).as_secs_f64(),
            quarantined: farm.quarantined(w),
        })
        .collect();
    Json(FarmState { jobs, workers }).into_response()
}

/// What the event stream watches of a job: results merged, the last one's time (ms
/// since the Unix epoch), and its state.
type Version = (u64, u64, &'static str);

/// The jobs `who` may see, with their [`Version`].
fn versions(app: &App, who: &Caller) -> Vec<(String, Version)> {
    let farm = app.shared.farm();
    let visible = farm.jobs.iter().filter(|e| who.may_touch(e.job.owner.as_deref()));
    visible
        .map(|e| {
            let j = &e.job;
            let at = j.last_merged_at.and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok());
            let at = at.map_or(0, |d| d.as_millis() as u64);
            (j.id.clone(), (j.merged, at, crate::farm::status::status_of(j, 0).state.name()))
        })
        .collect()
}

/// Server-Sent Events: `job` (data: `{"id":…,"merged":…,"merged_at_ms":…,"state":…}`) whenever a job
/// the caller may see merged a batch or changed state, checked every [`EVENT_POLL`].
pub(super) async fn events(State(app): State<App>, headers: HeaderMap) -> Response {
    let who = match caller(&app, &headers) {
        Ok(c) => c,
        Err(r) => return r.into_response(),
    };
    // Each stream polls the farm: their number is bounded.
    let open = app.event_streams.fetch_add(1, Ordering::SeqCst);
    if open >= MAX_EVENT_STREAMS {
        app.event_streams.fetch_sub(1, Ordering::SeqCst);
        return (StatusCode::SERVICE_UNAVAILABLE, format!("more than {MAX_EVENT_STREAMS} dashboards are open\n"))
            .into_response();
    }
    let stream = async_stream(app, who);
    Sse::new(stream).keep_alive(KeepAlive::default()).into_response()
}

/// Most event streams (open dashboard pages) at once.
const MAX_EVENT_STREAMS: usize = 256;

fn async_stream(app: App, who: Caller) -> impl tokio_stream::Stream<Item = Result<Event, Infallible>> {
    let (tx, rx) = tokio::sync::mpsc::channel(16);
    tokio::spawn(async move {
        let mut seen: std::collections::HashMap<String, Version> = Default::default();
        // A first line at once: the response (and the page's `open`) does not wait for
        // the first change.
        let _ = tx.send(Ok(Event::default().comment("tilefarm"))).await;
        // Ends when the page goes (the receiver is dropped), changes or not.
        while !tx.is_closed() {
            for (id, v) in versions(&app, &who) {
                if seen.get(&id) != Some(&v) {
                    let (merged, at, state) = v;
                    let data = serde_json::json!({ "id": id, "merged": merged, "merged_at_ms": at, "state": state });
                    if tx.send(Ok(Event::default().event("job").data(data.to_string()))).await.is_err() {
                        break;
                    }
                    seen.insert(id, v);
                }
            }
            tokio::time::sleep(EVENT_POLL).await;
        }
        app.event_streams.fetch_sub(1, Ordering::SeqCst);
    });
    tokio_stream::wrappers::ReceiverStream::new(rx)
}

/// The job `id` if `who` may see it, else the refusal.
fn visible(app: &App, who: &Caller, id: &str) -> Result<(), Refused> {
    let farm = app.shared.farm();
    match farm.entry(id) {
        Ok(e) if who.may_touch(e.job.owner.as_deref()) => Ok(()),
        Ok(_) => Err(Refused(StatusCode::FORBIDDEN, format!("{id} is not one of your jobs\n"))),
        Err(e) => Err(Refused(StatusCode::NOT_FOUND, format!("{e}\n"))),
    }
}

/// The caller, if they may see job `id`; else the refusal.
fn caller_of_job(app: &App, headers: &HeaderMap, id: &str) -> Result<Caller, Refused> {
    let who = caller(app, headers)?;
    visible(app, &who, id)?;
    Ok(who)
}

/// Where a job's image is read from.
enum Source {
    Live(ImageTiles),
    Stored(std::path::PathBuf),
}

#[derive(Deserialize)]
pub(super) struct ImageQuery {
    #[serde(default)]
    exposure: f32,
    /// `beauty` (the default), `noise` or `samples` ([`View`]).
    view: Option<String>,
}

/// The current merge as a PNG: tone-mapped after scaling by 2^exposure (stops, −20 to
/// 20), or a false-colour view of its noise or sample counts. The header
/// `X-Tilefarm-Scale: LOW HIGH` gives the values the view's colours span (its legend).
pub(super) async fn image_png(
    State(app): State<App>,
    headers: HeaderMap,
    Path(id): Path<String>,
    Query(q): Query<ImageQuery>,
) -> Response {
    if let Err(r) = caller_of_job(&app, &headers, &id) {
        return r.into_response();
    }
    let view = match q.view.as_deref().map(str::parse::<View>).unwrap_or(Ok(View::Beauty)) {
        Ok(v) => v,
        Err(e) => return (StatusCode::BAD_REQUEST, format!("{e}\n")).into_response(),
    };
    // A running job's image is read from its tiles in place; a finished one's, whose
    // sums have left memory, from the EXR it was stored as.
    let (source, merged, target, layers) = {
        let farm = app.shared.farm();
        match farm.entry(&id) {
            Ok(e) if e.job.width > 0 && !e.job.is_evicted() => {
                (Source::Live(e.job.image_tiles()), e.job.merged, e.job.noise_target(), e.job.layers)
            }
            Ok(e) if e.stored.is_some() => {
                let path = e.stored.clone().unwrap_or_default();
                (Source::Stored(path), e.job.merged, e.job.noise_target(), e.job.layers)
            }
            _ => return (StatusCode::NOT_FOUND, "no image for this job\n").into_response(),
        }
    };
    if view == View::Noise && !layers {
        let why = "this job keeps no variance: render with --aovs or --adaptive for a noise view\n";
        return (StatusCode::CONFLICT, why).into_response();
    }
    let stops = if q.exposure.is_finite() && view == View::Beauty { q.exposure.clamp(-20.0, 20.0) } else { 0.0 };
    let key = (id, merged, stops.to_bits(), view);
    let cached = app.images.lock().unwrap_or_else(|p| p.into_inner()).get(&key);
    let shown = match cached {
        Some(shown) => shown,
        None => {
            let scale = 2f32.powf(stops);
            let encoded = tokio::task::spawn_blocking(move || match source {
                Source::Live(tiles) => view_png(&tiles.mosaic(), view, scale, target),
                Source::Stored(path) => {
                    let image = tracer::output::read_exr(&path).map_err(|e| format!("the stored image: {e}"))?;
                    view_png(&image, view, scale, target)
                }
            })
            .await;
            match encoded {
                Ok(Ok(shown)) => {
                    let shown = Arc::new(shown);
                    app.images.lock().unwrap_or_else(|p| p.into_inner()).put(key, Arc::clone(&shown));
                    shown
                }
                Ok(Err(e)) => return (StatusCode::INTERNAL_SERVER_ERROR, e).into_response(),
                Err(e) => return (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()).into_response(),
            }
        }
    };
    let scale = format!("{} {}", shown.low, shown.high);
    let headers = [
        (header::CONTENT_TYPE, "image/png".to_string()),
        (header::CACHE_CONTROL, "no-store".to_string()),
        (HeaderName::from_static("x-tilefarm-scale"), scale),
    ];
    (headers, shown.png.clone()).into_response()
}

/// The finished (or so far) image as the EXR `fetch` writes.
pub(super) async fn image_exr(State(app): State<App>, headers: HeaderMap, Path(id): Path<String>) -> Response {
    if let Err(r) = caller_of_job(&app, &headers, &id) {
        return r.into_response();
    }
    let shared = Arc::clone(&app.shared);
    let name = id.clone();
    match tokio::task::spawn_blocking(move || shared.image_exr(&name)).await {
        Ok(Ok(b)) => {
            let disposition = format!("attachment; filename=\"{id}.exr\"");
            ([(header::CONTENT_TYPE, "image/x-exr".to_string()), (header::CONTENT_DISPOSITION, disposition)], b)
                .into_response()
        }
        Ok(Err(ImageError::Unknown(e))) => (StatusCode::NOT_FOUND, format!("{e}\n")).into_response(),
        Ok(Err(ImageError::None(m))) => (StatusCode::NOT_FOUND, format!("{m}\n")).into_response(),
        Ok(Err(ImageError::Failed(m))) => (StatusCode::INTERNAL_SERVER_ERROR, m).into_response(),
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()).into_response(),
    }
}

#[derive(Serialize)]
struct TileRow {
    x: u32,
    y: u32,
    w: u32,
    h: u32,
    /// Samples merged over samples wanted, 0 to 1 (1 once converged).
    done: f32,
    /// Adaptive sampling judged the tile converged and skipped its remaining units.
    converged: bool,
}

/// Each tile's progress, for the page's overlay.
pub(super) async fn tiles(State(app): State<App>, headers: HeaderMap, Path(id): Path<String>) -> Response {
    if let Err(r) = caller_of_job(&app, &headers, &id) {
        return r.into_response();
    }
    let farm = app.shared.farm();
    let Ok(e) = farm.entry(&id) else { return StatusCode::NOT_FOUND.into_response() };
    let rows: Vec<TileRow> = e
        .job
        .tile_progress()
        .into_iter()
        .map(|p| TileRow {
            x: p.tile.x0,
            y: p.tile.y0,
            w: p.tile.width,
            h: p.tile.height,
            done: p.done,
            converged: p.converged,
        })
        .collect();
    Json(rows).into_response()
}

#[derive(Deserialize)]
pub(super) struct Value {
    value: Option<u32>,
}

/// `POST /api/jobs/ID/{cancel,pause,resume,priority,spp}` (the last two with `?value=N`).
pub(super) async fn action(
    State(app): State<App>,
    headers: HeaderMap,
    Path((id, what)): Path<(String, String)>,
    Query(v): Query<Value>,
) -> Response {
    let who = match caller(&app, &headers) {
        Ok(c) => c,
        Err(r) => return r.into_response(),
    };
    if headers.get("x-tilefarm").is_none() {
        return (StatusCode::FORBIDDEN, "actions need the X-Tilefarm header (sent by the dashboard)\n").into_response();
    }
    if let Err(r) = visible(&app, &who, &id) {
        return r.into_response();
    }
    let change = match what.as_str() {
        "cancel" => {
            return match app.shared.cancel(&id) {
                Ok(s) => Json(JobRow::from(s)).into_response(),
                Err(e) => (StatusCode::BAD_REQUEST, format!("{e}\n")).into_response(),
            };
        }
        "pause" => JobChange { paused: Some(true), ..JobChange::default() },
        "resume" => JobChange { paused: Some(false), ..JobChange::default() },
        "priority" => JobChange { priority: Some(v.value.unwrap_or(0)), ..JobChange::default() },
        "spp" => JobChange { spp: Some(v.value.unwrap_or(0)), ..JobChange::default() },
        _ => return (StatusCode::NOT_FOUND, format!("no action {what}\n")).into_response(),
    };
    let mut farm = app.shared.farm();
    if let Err(e) = farm.update_job(&id, &change) {
        return (StatusCode::BAD_REQUEST, format!("{e}\n")).into_response();
    }
    tracing::info!(job = %id, ?change, by = %who.name, "job changed from the dashboard");
    match farm.status(&id, Instant::now()) {
        Ok(s) => Json(JobRow::from(s)).into_response(),
        Err(e) => (StatusCode::NOT_FOUND, format!("{e}\n")).into_response(),
    }
}
