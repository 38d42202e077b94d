//! The I/O around the worker's state machine ([`crate::machine`]): it performs each
//! [`Action`] — a gRPC call, a scene download and load, a render — in a tokio task, a
//! blocking thread or the render pool, and reports each outcome back to the machine as
//! an [`Event`] on one channel. Between events it sleeps until the machine's next
//! deadline, so backoffs never block heartbeats, submissions or rendering.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::sync::{mpsc, watch};
use tracing::{info, warn};

use crate::asset_cache::AssetCache;
use crate::executor::Executor;
use crate::link::{GrpcLink, Link};
use crate::machine::{Action, Event, Machine, SIGNAL_GRACE, Settings};
use crate::render_pool::RenderPool;
use crate::rpc;
use tracer::scene::prepared::PreparedScenes;

pub struct Config {
    pub coordinator: String,
    pub threads: usize,
    pub cache_dir: PathBuf,
    /// Where loaded scenes are kept prepared, and the most bytes kept; `None` keeps none.
    pub prepared: Option<(PathBuf, u64)>,
    pub max_backoff: Duration,
    /// Stop (exit 0) once the coordinator has been unreachable this long; `None` waits
    /// for it forever.
    pub give_up_after: Option<Duration>,
    /// Let scenes refer to files outside their job ([`AssetCache::trust_scene_paths`]).
    pub trust_scene_paths: bool,
    /// The farm's TLS folder: connect over TLS with the certificate `tls_name`.
    pub tls: Option<std::path::PathBuf>,
    pub tls_name: String,
}

/// Why the worker was asked to stop from outside.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stop {
    Signal,
    StdinEof,
}

impl From<Stop> for &'static str {
    fn from(s: Stop) -> Self {
        match s {
            Stop::Signal => "signal received",
            Stop::StdinEof => "standard input closed",
        }
    }
}

/// Runs a worker of a remote coordinator until it is asked to stop (by the coordinator
/// or `stop`). An error only for what retrying cannot fix: a bad address, an unusable
/// cache folder, the coordinator refusing this worker.
pub async fn run(config: Config, stop: watch::Receiver<Option<Stop>>) -> anyhow::Result<()> {
    let credentials = rpc::Credentials::from_env_and(config.tls.as_deref(), &config.tls_name)?;
    let client = rpc::connect(&config.coordinator, &credentials)?;
    let mut cache = AssetCache::open(&config.cache_dir)?;
    if let Some((dir, max_bytes)) = &config.prepared {
        // Without it every job loads its scene from the files: slower, never wrong.
        match PreparedScenes::open(dir, *max_bytes) {
            Ok(p) => cache = cache.with_prepared(p),
            Err(e) => warn!("{e}"),
        }
    }
    let cache = Arc::new(if config.trust_scene_paths { cache.trust_scene_paths() } else { cache });
    let pool = RenderPool::new(config.threads)?;
    info!(
        "worker {} starting: {} render threads, cache {}, coordinator {}",
        env!("CARGO_PKG_VERSION"),
        pool.threads(),
        cache.root().display(),
        config.coordinator
    );
    let settings = Settings {
        coordinator: config.coordinator.clone(),
        threads: pool.threads(),
        max_backoff: config.max_backoff,
        give_up_after: config.give_up_after,
    };
    let submitted = drive(GrpcLink::new(client, cache, config.max_backoff), Arc::new(pool), settings, stop).await?;
    info!("worker stopped ({submitted} result(s) submitted)");
    Ok(())
}

/// Drives the worker's machine over `link`, rendering on `executor`, until it is asked
/// to stop; returns the results the coordinator took.
pub async fn drive<L: Link, E: Executor>(
    link: L,
    executor: Arc<E>,
    settings: Settings,
    mut stop: watch::Receiver<Option<Stop>>,
) -> anyhow::Result<u64> {
    let (events, mut rx) = mpsc::unbounded_channel();
    let shell = Shell { link, executor, events };
    let mut m = Machine::new(settings, Instant::now());
    if let Some(why) = *stop.borrow_and_update() {
        m.begin_drain(why.into(), SIGNAL_GRACE, Instant::now());
    }
    let mut stop_open = true;
    loop {
        let now = Instant::now();
        for action in m.actions(now) {
            shell.perform(action);
        }
        if m.done(now) {
            break;
        }
        let wake = m.next_deadline(now).unwrap_or(now + Duration::from_secs(3600));
        tokio::select! {
            ev = rx.recv() => {
                if let Some(ev) = ev {
                    m.handle(ev, Instant::now())?;
                    // Everything else that is ready too, so that results finished together
                    // leave in one submission.
                    while let Ok(ev) = rx.try_recv() {
                        m.handle(ev, Instant::now())?;
                    }
                }
            }
            () = tokio::time::sleep_until(tokio::time::Instant::from_std(wake)) => {}
            changed = stop.changed(), if stop_open => match changed {
                Ok(()) => {
                    if let Some(why) = *stop.borrow_and_update() {
                        m.begin_drain(why.into(), SIGNAL_GRACE, Instant::now());
                    }
                }
                Err(_) => stop_open = false,
            },
        }
    }
    let unsent = m.unsent();
    if unsent > 0 {
        warn!("exiting with {unsent} result(s) not submitted: the coordinator will lease those units again");
    }
    Ok(m.submitted())
}

/// What performs the machine's actions: each in a task of its own (or the executor),
/// its outcome sent back on `events`.
struct Shell<L, E> {
    link: L,
    executor: Arc<E>,
    events: mpsc::UnboundedSender<Event>,
}

impl<L: Link, E: Executor> Shell<L, E> {
    fn perform(&self, action: Action) {
        let (link, tx) = (self.link.clone(), self.events.clone());
        match action {
            Action::Register => {
                let threads = self.executor.threads();
                tokio::spawn(async move {
                    let _ = tx.send(Event::Registered(link.register(threads).await));
                });
            }
            Action::Heartbeat { worker_id, held } => {
                tokio::spawn(async move {
                    let result = link.heartbeat(worker_id, held).await;
                    let _ = tx.send(Event::Heartbeat { worker_id, result });
                });
            }
            Action::Lease { worker_id, max_units } => {
                tokio::spawn(async move {
                    let result = link.lease(worker_id, max_units).await;
                    let _ = tx.send(Event::Leased { worker_id, result });
                });
            }
            Action::Submit { serials, worker_id, units } => {
                tokio::spawn(async move {
                    let result = link.submit(worker_id, units).await;
                    let _ = tx.send(Event::Submitted { serials, worker_id, result });
                });
            }
            Action::Prepare { job } => {
                info!("job {}: preparing scene '{}'", job.job_id, job.scene.path);
                tokio::spawn(async move {
                    let result = link.prepare(job.clone()).await;
                    let _ = tx.send(Event::JobReady { job, result });
                });
            }
            Action::Render { serial, job, tile, samples, cancel } => {
                self.executor.render(job, tile, samples, cancel, move |outcome| {
                    let _ = tx.send(Event::Rendered { serial, outcome });
                });
            }
        }
    }
}
