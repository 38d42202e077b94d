//! The farm's HTTP side (axum): the live dashboard at `/` (its endpoints under `/api`,
//! in `dashboard`), Prometheus metrics at `/metrics`, and health for orchestrators'
//! probes at `/healthz` (the process serves) and `/readyz` (the farm takes work). Metrics need the admin token whenever the farm has tokens — the same tokens as
//! the gRPC API, sent as `Authorization: Bearer …`; the health endpoints say nothing
//! about the farm and need none. Connections are served by hyper directly (rather than
//! `axum::serve`), which bounds the wait for a request's header and lets the listener
//! admit connections through its [`Gate`].

use std::convert::Infallible;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context as TaskContext, Poll};
use std::time::{Duration, Instant};

use anyhow::Context;
use axum::Router;
use axum::body::{Body, Bytes, HttpBody};
use axum::extract::State;
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use prometheus::{Encoder, Gauge, IntCounter, IntGauge, IntGaugeVec, Opts, Registry, TextEncoder};
use proto::auth::{Access, Role};
use tokio::net::TcpStream;
use tokio::sync::{oneshot, watch};
use tokio_stream::StreamExt;

use super::app::App;
use super::conn::{Accepted, Busy, Gate, Guarded, Limits};
use super::dashboard;
use crate::farm::Shared;
use crate::farm::job::JobPhase;

pub struct HttpServer {
    pub addr: SocketAddr,
    stop: Option<oneshot::Sender<()>>,
    task: tokio::task::JoinHandle<()>,
}

impl HttpServer {
    /// Binds `listen` (port 0: any free port) and serves in the background, holding
    /// connections to `limits`.
    pub async fn start(shared: Arc<Shared>, listen: &str, access: Access, limits: Limits) -> anyhow::Result<Self> {
        let listener =
            tokio::net::TcpListener::bind(listen).await.with_context(|| format!("--http {listen}: listening"))?;
        let addr = listener.local_addr()?;
        let app = Router::new()
            .route("/", get(dashboard::page))
            .route("/api/state", get(dashboard::state))
            .route("/api/events", get(dashboard::events))
            .route("/api/jobs/{id}/image.png", get(dashboard::image_png))
            .route("/api/jobs/{id}/image.exr", get(dashboard::image_exr))
            .route("/api/jobs/{id}/tiles", get(dashboard::tiles))
            .route("/api/jobs/{id}/{action}", post(dashboard::action))
            .route("/metrics", get(metrics))
            .route("/healthz", get(|| async { "ok\n" }))
            .route("/readyz", get(ready))
            .with_state(App {
                shared,
                access: Arc::new(access),
                images: Default::default(),
                event_streams: Default::default(),
            });
        let (stop, stopped) = oneshot::channel::<()>();
        let task = tokio::spawn(serve(listener, app, limits, stopped));
        Ok(Self { addr, stop: Some(stop), task })
    }

    pub fn url(&self) -> String {
        format!("http://{}", self.addr)
    }

    pub async fn stop(mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        let _ = tokio::time::timeout(Duration::from_secs(3), &mut self.task).await;
    }
}

/// Accepts until `stopped`, each connection in its own task; then lets the open ones
/// finish their requests and close.
async fn serve(listener: tokio::net::TcpListener, app: Router, limits: Limits, mut stopped: oneshot::Receiver<()>) {
    let mut incoming = Accepted::new(listener, Gate::new("HTTP", limits.max_pending), None);
    let (closing, closing_rx) = watch::channel(());
    loop {
        let io = tokio::select! {
            _ = &mut stopped => break,
            io = incoming.next() => io,
        };
        if let Some(Ok(io)) = io {
            tokio::spawn(connection(io, app.clone(), limits.header, closing_rx.clone()));
        }
    }
    drop(incoming);
    drop(closing_rx);
    let _ = closing.send(());
    closing.closed().await;
}

/// One HTTP/1.1 connection. Hyper closes it when a request's header (the first, or the
/// next on a kept-alive connection) takes longer than `header`; while a response is
/// being sent, the connection is busy, so its listener's gate does not close it to make
/// room.
async fn connection(io: Guarded<TcpStream>, app: Router, header: Duration, mut closing: watch::Receiver<()>) {
    let conn = Arc::clone(io.conn());
    let app = hyper_util::service::TowerToHyperService::new(app);
    let service = hyper::service::service_fn(move |request: hyper::Request<hyper::body::Incoming>| {
        let busy = conn.busy();
        let answer = hyper::service::Service::call(&app, request);
        async move {
            let response = answer.await?;
            Ok::<_, Infallible>(response.map(|body| Body::new(Held { body, _busy: busy })))
        }
    });
    let served = hyper::server::conn::http1::Builder::new()
        .timer(hyper_util::rt::TokioTimer::new())
        .header_read_timeout(header)
        .serve_connection(hyper_util::rt::TokioIo::new(io), service);
    tokio::pin!(served);
    tokio::select! {
        _ = served.as_mut() => return,
        _ = closing.changed() => served.as_mut().graceful_shutdown(),
    }
    let _ = served.await;
}

/// A response's body, keeping its connection busy until it is sent (or dropped).
struct Held {
    body: Body,
    _busy: Busy,
}

impl HttpBody for Held {
    type Data = Bytes;
    type Error = axum::Error;

    fn poll_frame(
        self: Pin<&mut Self>,
        cx: &mut TaskContext<'_>,
    ) -> Poll<Option<Result<hyper::body::Frame<Bytes>, axum::Error>>> {
        Pin::new(&mut self.get_mut().body).poll_frame(cx)
    }

    fn is_end_stream(&self) -> bool {
        self.body.is_end_stream()
    }

    fn size_hint(&self) -> hyper::body::SizeHint {
        self.body.size_hint()
    }
}

/// The caller's role from the `Authorization` header, or why it is refused.
fn caller_role(access: &Access, headers: &HeaderMap) -> Result<Role, String> {
    let bearer = headers.get(header::AUTHORIZATION).and_then(|v| v.to_str().ok());
    access.identify(bearer, None).map(|c| c.role).map_err(|e| e.message().to_string())
}

async fn metrics(State(app): State<App>, headers: HeaderMap) -> Response {
    match caller_role(&app.access, &headers) {
        Ok(Role::Admin) => {}
        Ok(_) => return (StatusCode::FORBIDDEN, "metrics need the farm's admin token\n").into_response(),
        Err(why) => {
            return (StatusCode::UNAUTHORIZED, [(header::WWW_AUTHENTICATE, "Bearer")], format!("{why}\n"))
                .into_response();
        }
    }
    match exposition(&app.shared) {
        Ok(text) => ([(header::CONTENT_TYPE, TextEncoder::new().format_type().to_string())], text).into_response(),
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, format!("{e:#}\n")).into_response(),
    }
}

async fn ready(State(app): State<App>) -> Response {
    if app.shared.farm().shutting_down {
        (StatusCode::SERVICE_UNAVAILABLE, "shutting down\n").into_response()
    } else {
        "ready\n".into_response()
    }
}

/// The farm's metrics in Prometheus' text format: a registry made for this scrape,
/// filled from one snapshot of the farm (so that the numbers agree with each other),
/// plus the meters that live across scrapes.
fn exposition(shared: &Shared) -> anyhow::Result<String> {
    let registry = Registry::new();
    let counter = |name: &str, help: &str, value: u64| -> anyhow::Result<()> {
        let c = IntCounter::new(name, help)?;
        c.inc_by(value);
        registry.register(Box::new(c))?;
        Ok(())
    };
    let jobs = IntGaugeVec::new(Opts::new("tilefarm_jobs", "Jobs the farm lists, by state"), &["state"])?;
    let workers = IntGaugeVec::new(Opts::new("tilefarm_workers", "Registered workers, by state"), &["state"])?;
    let rate = Gauge::new("tilefarm_samples_per_second", "Samples per second over the running jobs")?;
    let queued = IntGauge::new("tilefarm_units_queued", "Units waiting for a worker in running, unpaused jobs")?;
    let units = {
        let farm = shared.farm();
        let now = Instant::now();
        for state in ["loading", "running", "paused", "done", "failed", "cancelled"] {
            jobs.with_label_values(&[state]).set(0);
        }
        let mut waiting = 0u64;
        let mut samples_per_s = 0.0;
        for e in &farm.jobs {
            let j = &e.job;
            let state = match &j.phase {
                JobPhase::Queued => "queued",
                JobPhase::Loading => "loading",
                JobPhase::Running if j.share.paused => "paused",
                JobPhase::Running => "running",
                JobPhase::Done => "done",
                JobPhase::Failed(_) => "failed",
                JobPhase::Cancelled => "cancelled",
            };
            jobs.with_label_values(&[state]).inc();
            if state == "running" {
                waiting += j.queued() as u64;
                samples_per_s += j.samples_per_second();
            }
        }
        let lease = farm.config.lease;
        for state in ["busy", "idle", "silent", "quarantined"] {
            workers.with_label_values(&[state]).set(0);
        }
        for w in farm.workers.values() {
            let held: usize = farm.jobs.iter().map(|e| e.job.held_by(w.id)).sum();
            let state = if farm.quarantined(w) {
                "quarantined"
            } else if now.saturating_duration_since(w.last_seen) > lease {
                "silent"
            } else if held > 0 {
                "busy"
            } else {
                "idle"
            };
            workers.with_label_values(&[state]).inc();
        }
        rate.set(samples_per_s);
        queued.set(i64::try_from(waiting).unwrap_or(i64::MAX));
        farm.unit_counters()
    };
    counter("tilefarm_units_leased_total", "Units handed to workers (a re-lease counts again)", units.leased)?;
    counter("tilefarm_units_completed_total", "Unit results merged into their job's image", units.completed)?;
    counter("tilefarm_units_lapsed_total", "Leases that ran out before their result came", units.lapsed)?;
    counter("tilefarm_units_rejected_total", "Unit results refused", units.rejected)?;
    counter("tilefarm_units_verified_total", "Units merged once a second worker agreed bit for bit", units.verified)?;
    counter("tilefarm_units_mismatched_total", "Checks whose answers disagreed", units.mismatched)?;
    registry.register(Box::new(jobs))?;
    registry.register(Box::new(workers))?;
    registry.register(Box::new(rate))?;
    registry.register(Box::new(queued))?;
    registry.register(Box::new(shared.meters.merge_seconds.clone()))?;
    registry.register(Box::new(shared.meters.bytes_in.clone()))?;
    registry.register(Box::new(shared.meters.bytes_out.clone()))?;
    let mut out = Vec::new();
    TextEncoder::new().encode(&registry.gather(), &mut out)?;
    Ok(String::from_utf8(out)?)
}
