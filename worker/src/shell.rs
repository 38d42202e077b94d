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

use crate::asset_cache::{self, AssetCache};
use crate::machine::{Action, Event, Grant, Machine, Registration, Renewal, SIGNAL_GRACE, Settings};
use crate::render_pool::RenderPool;
use crate::rpc::{self, Client};
use proto::wire;

const REGISTER_TIMEOUT: Duration = Duration::from_secs(5);
const LEASE_TIMEOUT: Duration = Duration::from_secs(10);
const HEARTBEAT_TIMEOUT: Duration = Duration::from_secs(5);
const SUBMIT_TIMEOUT: Duration = Duration::from_secs(30);

pub struct Config {
    pub coordinator: String,
    pub threads: usize,
    pub cache_dir: PathBuf,
    pub max_backoff: Duration,
    /// Stop (exit 0) once the coordinator has been unreachable this long; `None` waits
    /// for it forever.
    pub give_up_after: Option<Duration>,
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

/// What performs the machine's actions.
struct Shell {
    client: Client,
    cache: Arc<AssetCache>,
    pool: RenderPool,
    max_backoff: Duration,
    events: mpsc::UnboundedSender<Event>,
}

/// Runs the worker until it is asked to stop (by the coordinator or `stop`). An error
/// only for what retrying cannot fix: a bad address, an unusable cache folder, the
/// coordinator refusing this worker.
pub async fn run(config: Config, mut stop: watch::Receiver<Option<Stop>>) -> anyhow::Result<()> {
    let client = rpc::connect(&config.coordinator)?;
    let cache = Arc::new(AssetCache::open(&config.cache_dir)?);
    let pool = RenderPool::new(config.threads)?;
    let (events, mut rx) = mpsc::unbounded_channel();
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
    let shell = Shell { client, cache, pool, max_backoff: config.max_backoff, events };
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
    info!("worker stopped ({} result(s) submitted)", m.submitted());
    Ok(())
}

impl Shell {
    fn perform(&self, action: Action) {
        let mut client = self.client.clone();
        let tx = self.events.clone();
        match action {
            Action::Register => {
                let request = proto::RegisterRequest {
                    protocol_version: proto::PROTOCOL_VERSION,
                    threads: u32::try_from(self.pool.threads()).unwrap_or(u32::MAX),
                    hostname: hostname(),
                    version: env!("CARGO_PKG_VERSION").to_string(),
                };
                tokio::spawn(async move {
                    let result = rpc::call(REGISTER_TIMEOUT, client.register(request)).await.map(|r| Registration {
                        worker_id: r.worker_id,
                        lease_ms: r.lease_ms,
                        heartbeat_ms: r.heartbeat_ms,
                    });
                    let _ = tx.send(Event::Registered(result));
                });
            }
            Action::Heartbeat { worker_id, held } => {
                let held = held.iter().map(wire::unit_key_to_proto).collect();
                let request = proto::HeartbeatRequest { worker_id, held };
                tokio::spawn(async move {
                    let result = rpc::call(HEARTBEAT_TIMEOUT, client.heartbeat(request)).await.map(|r| Renewal {
                        abandon: r.abandon.into_iter().map(wire::unit_key_from_proto).collect(),
                        shutdown: r.shutdown,
                    });
                    let _ = tx.send(Event::Heartbeat { worker_id, result });
                });
            }
            Action::Lease { worker_id, max_units } => {
                tokio::spawn(async move {
                    let request = proto::LeaseRequest { worker_id, max_units };
                    let result = rpc::call(LEASE_TIMEOUT, client.lease(request)).await.map(|r| Grant {
                        units: r.units.into_iter().map(wire::unit_from_proto).collect(),
                        retry_after_ms: r.retry_after_ms,
                        shutdown: r.shutdown,
                    });
                    let _ = tx.send(Event::Leased { worker_id, result });
                });
            }
            Action::Submit { serial, worker_id, unit } => {
                let message = wire::result_to_proto(worker_id, &unit.key, unit.samples, &unit.acc, unit.rays);
                tokio::spawn(async move {
                    let result = rpc::call(SUBMIT_TIMEOUT, client.submit_result(message)).await.map(|r| r.accepted);
                    let _ = tx.send(Event::Submitted { serial, worker_id, result });
                });
            }
            Action::Prepare { job } => {
                let (cache, max_backoff) = (self.cache.clone(), self.max_backoff);
                tokio::spawn(async move {
                    // An inner task, so that even a panic is reported and the job not stuck.
                    let task = tokio::spawn(asset_cache::prepare_job(client, cache, job.clone(), max_backoff));
                    let result = match task.await {
                        Ok(Ok(loaded)) => Ok(Arc::new(loaded)),
                        Ok(Err(e)) => Err(format!("{e:#}")),
                        Err(e) => Err(format!("scene preparation failed: {e}")),
                    };
                    let _ = tx.send(Event::JobReady { job, result });
                });
            }
            Action::Render { serial, job, tile, samples, cancel } => {
                self.pool.spawn(job, tile, samples, cancel, move |outcome| {
                    let _ = tx.send(Event::Rendered { serial, outcome });
                });
            }
        }
    }
}

/// This machine's name, for the coordinator's worker list.
fn hostname() -> String {
    ["/proc/sys/kernel/hostname", "/etc/hostname"]
        .iter()
        .find_map(|p| std::fs::read_to_string(p).ok().map(|s| s.trim().to_string()).filter(|s| !s.is_empty()))
        .or_else(|| std::env::var("HOSTNAME").ok().filter(|s| !s.is_empty()))
        .or_else(|| std::env::var("COMPUTERNAME").ok().filter(|s| !s.is_empty()))
        .unwrap_or_else(|| "unknown".to_string())
}
