//! The worker's state machine: register, lease, render, submit, heartbeat, stop.
//!
//! One task owns all the state ([`Worker`]). Everything that takes time — an RPC, a
//! scene download and load, a render — runs elsewhere (a tokio task, a blocking thread,
//! the render pool) and reports back as an [`Event`] on one channel. The loop applies
//! events, starts whatever operation is due, and sleeps until the next deadline, so
//! backoffs never block heartbeats, submissions or rendering.
//!
//! Each leased unit lives in a [`Slot`]:
//!
//! ```text
//!   WaitingScene ──scene ready──▶ InPool ──rendered──▶ Finished ──submitted/rejected──▶ (gone)
//!        │                          │                      │
//!        └──abandon/fail──▶ (gone)  └──abandon──▶ Abandoned ──thread returns──▶ (gone)
//! ```
//!
//! Prefetch: the worker keeps up to `2 × threads` units in WaitingScene/InPool/Abandoned,
//! so the render pool always has a queued unit when a thread finishes one.

use std::collections::{BTreeMap, HashSet, VecDeque};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::anyhow;
use tokio::sync::{mpsc, watch};
use tokio::time::Instant;
use tracing::{debug, error, info, warn};

use crate::asset_cache::{self, AssetCache, LoadedJob, SceneCache};
use crate::render_pool::{RenderOutcome, RenderPool};
use crate::rpc::{self, Backoff, Client, RpcFailure};
use proto::wire::{self, UnitKey, WorkUnit};

const REGISTER_TIMEOUT: Duration = Duration::from_secs(5);
const LEASE_TIMEOUT: Duration = Duration::from_secs(10);
const HEARTBEAT_TIMEOUT: Duration = Duration::from_secs(5);
const SUBMIT_TIMEOUT: Duration = Duration::from_secs(30);
/// How long finished results may take to reach the coordinator after a signal.
const SIGNAL_GRACE: Duration = Duration::from_secs(2);
/// ... and after the coordinator asked the worker to stop.
const SHUTDOWN_GRACE: Duration = Duration::from_secs(5);
/// Retry interval while stopping, whatever the backoff has grown to.
const DRAIN_RETRY: Duration = Duration::from_millis(250);
/// Wait before asking again after a lease reply without usable units and no hint.
const DEFAULT_IDLE_WAIT: Duration = Duration::from_millis(500);
/// Units of a job whose scene failed to load are dropped for this long.
const FAILED_JOB_MEMORY: Duration = Duration::from_secs(30);
/// Results sent concurrently (HTTP/2 multiplexes them on one connection).
const MAX_SUBMITS_IN_FLIGHT: usize = 4;
/// Loaded scenes kept beyond those in use.
const SCENE_CACHE_JOBS: usize = 2;

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

/// Completions of work done outside the loop.
enum Event {
    Registered(Result<proto::RegisterReply, RpcFailure>),
    Leased { worker_id: u64, result: Result<proto::LeaseReply, RpcFailure> },
    Heartbeat { worker_id: u64, result: Result<proto::HeartbeatReply, RpcFailure> },
    Submitted { serial: u64, worker_id: u64, result: Result<proto::SubmitReply, RpcFailure> },
    JobReady { job: Arc<wire::JobSpec>, result: Result<Arc<LoadedJob>, String> },
    Rendered { serial: u64, outcome: RenderOutcome },
}

/// One kind of repeated RPC: at most one in flight, the next not before `next_at`.
struct Op {
    in_flight: bool,
    next_at: Instant,
    backoff: Backoff,
}

impl Op {
    fn new(now: Instant, max_backoff: Duration) -> Self {
        Self { in_flight: false, next_at: now, backoff: Backoff::new(max_backoff) }
    }

    fn due(&self, now: Instant) -> bool {
        !self.in_flight && now >= self.next_at
    }

    /// After a success: go again at once (or at `next`), with the backoff reset.
    fn succeeded(&mut self, next: Instant) {
        self.in_flight = false;
        self.backoff.reset();
        self.next_at = next;
    }

    /// After a failure: go again after the backoff's next delay (at most `cap`).
    fn failed(&mut self, now: Instant, cap: Option<Duration>) -> Duration {
        self.in_flight = false;
        let mut d = self.backoff.next_delay();
        if let Some(cap) = cap {
            d = d.min(cap);
        }
        self.next_at = now + d;
        d
    }
}

enum SlotState {
    /// Waiting for the job's scene to be downloaded and loaded.
    WaitingScene,
    /// Given to the render pool: queued there, or rendering.
    InPool,
    /// Abandoned while in the pool: no longer reported as held; its result is discarded
    /// when the thread returns (until then it occupies a place of the prefetch window).
    Abandoned,
    /// Rendered; held until `SubmitResult` succeeds or is refused.
    Finished { result: Box<proto::UnitResult>, submitting: bool },
}

struct Slot {
    unit: WorkUnit,
    cancel: Arc<AtomicBool>,
    state: SlotState,
    /// The scene, while the unit is in the pool.
    loaded: Option<Arc<LoadedJob>>,
}

impl Slot {
    /// Is this unit reported to the coordinator as held?
    fn held(&self) -> bool {
        !matches!(self.state, SlotState::Abandoned)
    }

    /// Does this unit occupy a place in the prefetch window?
    fn pending_render(&self) -> bool {
        matches!(self.state, SlotState::WaitingScene | SlotState::InPool | SlotState::Abandoned)
    }

    fn unsent(&self) -> bool {
        matches!(self.state, SlotState::Finished { submitting: false, .. })
    }
}

struct Drain {
    deadline: Instant,
}

struct Worker {
    url: String,
    client: Client,
    cache: Arc<AssetCache>,
    pool: RenderPool,
    max_backoff: Duration,
    events: mpsc::UnboundedSender<Event>,

    worker_id: Option<u64>,
    heartbeat_every: Duration,
    register: Op,
    lease: Op,
    heartbeat: Op,
    /// Submissions are not an [`Op`]: several may be in flight.
    submits_in_flight: usize,
    submit_next_at: Instant,
    submit_backoff: Backoff,
    heartbeat_failures: u32,

    slots: BTreeMap<u64, Slot>,
    next_serial: u64,
    loading: HashSet<String>,
    scenes: SceneCache,
    /// Jobs whose scene failed to load, and when.
    failed_jobs: VecDeque<(Arc<wire::JobSpec>, Instant)>,
    drain: Option<Drain>,
    submitted: u64,
    /// The last time the coordinator answered at all, and how long to wait for it.
    last_contact: Instant,
    give_up_after: Option<Duration>,
}

/// Runs the worker until it is asked to stop (by the coordinator or `stop`). An error
/// only for what retrying cannot fix: a bad address, an unusable cache folder, the
/// coordinator refusing this worker.
pub async fn run(config: Config, mut stop: watch::Receiver<Option<Stop>>) -> anyhow::Result<()> {
    let client = rpc::connect(&config.coordinator)?;
    let cache = Arc::new(AssetCache::open(&config.cache_dir)?);
    let pool = RenderPool::new(config.threads)?;
    let (events, mut rx) = mpsc::unbounded_channel();
    let now = Instant::now();
    let mut w = Worker {
        url: config.coordinator.clone(),
        client,
        cache,
        pool,
        max_backoff: config.max_backoff,
        events,
        worker_id: None,
        heartbeat_every: Duration::from_secs(1),
        register: Op::new(now, config.max_backoff),
        lease: Op::new(now, config.max_backoff),
        heartbeat: Op::new(now, config.max_backoff),
        submits_in_flight: 0,
        submit_next_at: now,
        submit_backoff: Backoff::new(config.max_backoff),
        heartbeat_failures: 0,
        slots: BTreeMap::new(),
        next_serial: 0,
        loading: HashSet::new(),
        scenes: SceneCache::new(SCENE_CACHE_JOBS),
        failed_jobs: VecDeque::new(),
        drain: None,
        submitted: 0,
        last_contact: now,
        give_up_after: config.give_up_after,
    };
    info!(
        "worker {} starting: {} render threads, cache {}, coordinator {}",
        env!("CARGO_PKG_VERSION"),
        w.pool.threads(),
        w.cache.root().display(),
        w.url
    );
    if let Some(why) = *stop.borrow_and_update() {
        w.begin_drain(why.into(), SIGNAL_GRACE, now);
    }
    let mut stop_open = true;
    loop {
        let now = Instant::now();
        if let Some(limit) = w.give_up_after
            && now.duration_since(w.last_contact) > limit
            && w.drain.is_none()
        {
            warn!("the coordinator has been unreachable for {limit:?}: giving up as --give-up-after-ms asks");
            w.begin_drain("coordinator gone", SIGNAL_GRACE, now);
        }
        w.start_due(now);
        if w.done(now) {
            break;
        }
        let wake = w.next_deadline(now).unwrap_or(now + Duration::from_secs(3600));
        tokio::select! {
            ev = rx.recv() => {
                if let Some(ev) = ev {
                    w.handle(ev, Instant::now())?;
                }
            }
            () = tokio::time::sleep_until(wake) => {}
            changed = stop.changed(), if stop_open => match changed {
                Ok(()) => {
                    if let Some(why) = *stop.borrow_and_update() {
                        w.begin_drain(why.into(), SIGNAL_GRACE, Instant::now());
                    }
                }
                Err(_) => stop_open = false,
            },
        }
    }
    let unsent = w.slots.values().filter(|s| matches!(s.state, SlotState::Finished { .. })).count();
    if unsent > 0 {
        warn!("exiting with {unsent} result(s) not submitted: the coordinator will lease those units again");
    }
    info!("worker stopped ({} result(s) submitted)", w.submitted);
    Ok(())
}

impl From<Stop> for &'static str {
    fn from(s: Stop) -> Self {
        match s {
            Stop::Signal => "signal received",
            Stop::StdinEof => "standard input closed",
        }
    }
}

impl Worker {
    // ------------------------------------------------------------ scheduling

    fn draining(&self) -> bool {
        self.drain.is_some()
    }

    fn has_finished(&self) -> bool {
        self.slots.values().any(|s| matches!(s.state, SlotState::Finished { .. }))
    }

    fn has_unsent(&self) -> bool {
        self.slots.values().any(Slot::unsent)
    }

    /// How many more units to lease: fill the prefetch window of `2 × threads`, unless
    /// results are piling up unsent.
    fn lease_want(&self) -> usize {
        let threads = self.pool.threads();
        let pending = self.slots.values().filter(|s| s.pending_render()).count();
        let finished = self.slots.values().filter(|s| matches!(s.state, SlotState::Finished { .. })).count();
        if finished >= 4 * threads { 0 } else { (2 * threads).saturating_sub(pending) }
    }

    fn register_wanted(&self) -> bool {
        self.worker_id.is_none() && !self.register.in_flight && (!self.draining() || self.has_finished())
    }

    fn heartbeat_wanted(&self) -> bool {
        self.worker_id.is_some() && !self.draining() && !self.heartbeat.in_flight
    }

    fn lease_wanted(&self) -> bool {
        self.worker_id.is_some() && !self.draining() && !self.lease.in_flight && self.lease_want() > 0
    }

    fn submit_wanted(&self) -> bool {
        self.worker_id.is_some() && self.submits_in_flight < MAX_SUBMITS_IN_FLIGHT && self.has_unsent()
    }

    /// Starts every operation whose time has come.
    fn start_due(&mut self, now: Instant) {
        if self.register_wanted() && self.register.due(now) {
            self.spawn_register();
        }
        if self.heartbeat_wanted() && self.heartbeat.due(now) {
            self.spawn_heartbeat(now);
        }
        if self.lease_wanted() && self.lease.due(now) {
            self.spawn_lease();
        }
        while self.submit_wanted() && now >= self.submit_next_at {
            self.spawn_submit();
        }
    }

    /// The earliest future time at which something is due.
    fn next_deadline(&self, now: Instant) -> Option<Instant> {
        let candidates = [
            self.drain.as_ref().map(|d| d.deadline),
            self.register_wanted().then_some(self.register.next_at),
            self.heartbeat_wanted().then_some(self.heartbeat.next_at),
            self.lease_wanted().then_some(self.lease.next_at),
            self.submit_wanted().then_some(self.submit_next_at),
        ];
        candidates.into_iter().flatten().filter(|&t| t > now).min()
    }

    /// Stopping, and either out of time or with nothing left to submit?
    fn done(&self, now: Instant) -> bool {
        match &self.drain {
            None => false,
            Some(d) => now >= d.deadline || (!self.has_finished() && self.submits_in_flight == 0),
        }
    }

    /// Stop taking work: drop what has not been rendered, keep submitting what has,
    /// for at most `grace`.
    fn begin_drain(&mut self, why: &str, grace: Duration, now: Instant) {
        let deadline = now + grace;
        match &mut self.drain {
            Some(d) => d.deadline = d.deadline.min(deadline),
            None => {
                let finished = self.slots.values().filter(|s| matches!(s.state, SlotState::Finished { .. })).count();
                info!("{why}: stopping (submitting {finished} finished result(s), dropping unrendered units)");
                self.drain = Some(Drain { deadline });
            }
        }
        self.slots.retain(|_, s| match s.state {
            SlotState::WaitingScene => false,
            SlotState::InPool => {
                s.cancel.store(true, Ordering::Relaxed);
                s.state = SlotState::Abandoned;
                true
            }
            _ => true,
        });
        self.submit_next_at = now;
    }

    // ------------------------------------------------------------ starting operations

    fn spawn_register(&mut self) {
        self.register.in_flight = true;
        let request = proto::RegisterRequest {
            protocol_version: proto::PROTOCOL_VERSION,
            threads: u32::try_from(self.pool.threads()).unwrap_or(u32::MAX),
            hostname: hostname(),
            version: env!("CARGO_PKG_VERSION").to_string(),
        };
        let mut client = self.client.clone();
        let tx = self.events.clone();
        tokio::spawn(async move {
            let result = rpc::call(REGISTER_TIMEOUT, client.register(request)).await;
            let _ = tx.send(Event::Registered(result));
        });
    }

    fn spawn_heartbeat(&mut self, now: Instant) {
        let Some(worker_id) = self.worker_id else { return };
        self.heartbeat.in_flight = true;
        self.heartbeat.next_at = now + self.heartbeat_every;
        let held = self.slots.values().filter(|s| s.held()).map(|s| wire::unit_key_to_proto(&s.unit.key)).collect();
        let request = proto::HeartbeatRequest { worker_id, held };
        let mut client = self.client.clone();
        let tx = self.events.clone();
        tokio::spawn(async move {
            let result = rpc::call(HEARTBEAT_TIMEOUT, client.heartbeat(request)).await;
            let _ = tx.send(Event::Heartbeat { worker_id, result });
        });
    }

    fn spawn_lease(&mut self) {
        let Some(worker_id) = self.worker_id else { return };
        let max_units = u32::try_from(self.lease_want()).unwrap_or(u32::MAX);
        self.lease.in_flight = true;
        let mut client = self.client.clone();
        let tx = self.events.clone();
        tokio::spawn(async move {
            let result = rpc::call(LEASE_TIMEOUT, client.lease(proto::LeaseRequest { worker_id, max_units })).await;
            let _ = tx.send(Event::Leased { worker_id, result });
        });
    }

    fn spawn_submit(&mut self) {
        let Some(worker_id) = self.worker_id else { return };
        let Some((&serial, slot)) = self.slots.iter_mut().find(|(_, s)| s.unsent()) else { return };
        let SlotState::Finished { result, submitting } = &mut slot.state else { return };
        *submitting = true;
        let mut message = (**result).clone();
        message.worker_id = worker_id;
        self.submits_in_flight += 1;
        let mut client = self.client.clone();
        let tx = self.events.clone();
        tokio::spawn(async move {
            let result = rpc::call(SUBMIT_TIMEOUT, client.submit_result(message)).await;
            let _ = tx.send(Event::Submitted { serial, worker_id, result });
        });
    }

    fn spawn_prepare(&mut self, job: Arc<wire::JobSpec>) {
        self.loading.insert(job.job_id.clone());
        info!("job {}: preparing scene '{}'", job.job_id, job.scene.path);
        let (client, cache, tx, max_backoff) =
            (self.client.clone(), self.cache.clone(), self.events.clone(), self.max_backoff);
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

    // ------------------------------------------------------------ events

    fn handle(&mut self, event: Event, now: Instant) -> anyhow::Result<()> {
        let answered = match &event {
            Event::Registered(r) => !matches!(r, Err(RpcFailure::Transport(_))),
            Event::Leased { result, .. } => !matches!(result, Err(RpcFailure::Transport(_))),
            Event::Heartbeat { result, .. } => !matches!(result, Err(RpcFailure::Transport(_))),
            Event::Submitted { result, .. } => !matches!(result, Err(RpcFailure::Transport(_))),
            Event::JobReady { .. } | Event::Rendered { .. } => false,
        };
        if answered {
            self.last_contact = now;
        }
        match event {
            Event::Registered(result) => self.on_registered(result, now)?,
            Event::Leased { worker_id, result } => self.on_leased(worker_id, result, now),
            Event::Heartbeat { worker_id, result } => self.on_heartbeat(worker_id, result, now),
            Event::Submitted { serial, worker_id, result } => self.on_submitted(serial, worker_id, result, now),
            Event::JobReady { job, result } => self.on_job_ready(job, result, now),
            Event::Rendered { serial, outcome } => self.on_rendered(serial, outcome),
        }
        Ok(())
    }

    fn on_registered(&mut self, result: Result<proto::RegisterReply, RpcFailure>, now: Instant) -> anyhow::Result<()> {
        match result {
            Ok(reply) => {
                self.register.succeeded(now);
                let heartbeat_ms = match (reply.heartbeat_ms, reply.lease_ms) {
                    (0, 0) => 1000,
                    (0, lease) => lease / 3,
                    (hb, _) => hb,
                };
                self.heartbeat_every = Duration::from_millis(u64::from(heartbeat_ms).clamp(50, 60_000));
                self.worker_id = Some(reply.worker_id);
                self.heartbeat_failures = 0;
                // Renew whatever is held at once (after a re-registration), then lease.
                self.heartbeat.next_at = now;
                self.lease.succeeded(now);
                self.submit_backoff.reset();
                self.submit_next_at = now;
                info!(
                    "registered with {} as worker {} (lease {} ms, heartbeat every {:?})",
                    self.url, reply.worker_id, reply.lease_ms, self.heartbeat_every
                );
            }
            Err(RpcFailure::Rejected(status)) => {
                return Err(anyhow!(
                    "the coordinator at {} refused to register this worker ({:?}): {}",
                    self.url,
                    status.code(),
                    status.message()
                ));
            }
            Err(e) => {
                let d = self.register.failed(now, self.drain.as_ref().map(|_| DRAIN_RETRY));
                warn!("cannot register with {}: {e}; retrying in {d:?}", self.url);
            }
        }
        Ok(())
    }

    /// The coordinator no longer knows `worker_id`: register again (once, however many
    /// calls report it).
    fn lost_registration(&mut self, worker_id: u64, message: &str, now: Instant) {
        if self.worker_id == Some(worker_id) {
            warn!("the coordinator does not know worker {worker_id} ({message}); registering again");
            self.worker_id = None;
            self.register.backoff.reset();
            self.register.next_at = now;
        }
    }

    fn on_leased(&mut self, worker_id: u64, result: Result<proto::LeaseReply, RpcFailure>, now: Instant) {
        match result {
            Ok(reply) => {
                if reply.shutdown {
                    self.lease.succeeded(now);
                    self.begin_drain("the coordinator asked this worker to stop", SHUTDOWN_GRACE, now);
                    return;
                }
                if self.draining() {
                    self.lease.succeeded(now);
                    return;
                }
                let offered = reply.units.len();
                let mut accepted = 0;
                for unit in reply.units {
                    accepted += usize::from(self.accept(unit, now));
                }
                let next = if accepted > 0 {
                    now
                } else {
                    let wait = match reply.retry_after_ms {
                        0 => DEFAULT_IDLE_WAIT,
                        ms => Duration::from_millis(u64::from(ms).min(60_000)),
                    };
                    debug!("lease: {offered} unit(s) offered, none taken; asking again in {wait:?}");
                    now + wait
                };
                self.lease.succeeded(next);
            }
            Err(RpcFailure::UnknownWorker(m)) => {
                self.lease.succeeded(now);
                self.lost_registration(worker_id, &m, now);
            }
            Err(e) => {
                let d = self.lease.failed(now, None);
                warn!("lease failed: {e}; retrying in {d:?}");
            }
        }
    }

    /// Takes a leased unit: checks it, and queues it for its scene or the render pool.
    /// False if it was dropped.
    fn accept(&mut self, unit: proto::Unit, now: Instant) -> bool {
        let unit = match wire::unit_from_proto(unit) {
            Ok(u) => u,
            Err(e) => {
                warn!("dropping a malformed unit: {e}");
                return false;
            }
        };
        self.failed_jobs.retain(|(_, at)| now.duration_since(*at) < FAILED_JOB_MEMORY);
        if self.failed_jobs.iter().any(|(j, _)| *j == unit.job) {
            debug!("unit {}: its scene failed to load; dropping it", unit.key);
            return false;
        }
        if self.slots.values().any(|s| s.held() && s.unit.key == unit.key) {
            debug!("unit {} is already held", unit.key);
            return false;
        }
        let serial = self.next_serial;
        self.next_serial += 1;
        let job = unit.job.clone();
        self.slots.insert(
            serial,
            Slot { unit, cancel: Arc::new(AtomicBool::new(false)), state: SlotState::WaitingScene, loaded: None },
        );
        if let Some(loaded) = self.loaded_job(&job) {
            self.dispatch(serial, loaded)
        } else {
            if !self.loading.contains(&job.job_id) {
                self.spawn_prepare(job);
            }
            true
        }
    }

    /// A job's loaded scene: from the cache, or from a unit that is using it.
    fn loaded_job(&mut self, job: &wire::JobSpec) -> Option<Arc<LoadedJob>> {
        if let Some(j) = self.scenes.get(job) {
            return Some(j);
        }
        let j = self.slots.values().find_map(|s| s.loaded.as_ref().filter(|l| l.spec == *job))?.clone();
        self.scenes.insert(j.clone());
        Some(j)
    }

    /// Gives a unit whose scene is loaded to the render pool. False if it was dropped.
    fn dispatch(&mut self, serial: u64, loaded: Arc<LoadedJob>) -> bool {
        let Some(slot) = self.slots.get_mut(&serial) else { return false };
        let (tile, samples) = (slot.unit.tile, slot.unit.samples);
        let (w, h) = (loaded.scene.camera.width, loaded.scene.camera.height);
        // The tile's end cannot overflow: proto::wire checked it.
        if tile.x0 + tile.width > w || tile.y0 + tile.height > h {
            warn!(
                "unit {}: tile {}×{} at ({}, {}) lies outside the {w}×{h} image; dropping it",
                slot.unit.key, tile.width, tile.height, tile.x0, tile.y0
            );
            self.slots.remove(&serial);
            return false;
        }
        slot.state = SlotState::InPool;
        slot.loaded = Some(loaded.clone());
        let tx = self.events.clone();
        self.pool.spawn(loaded, tile, samples, slot.cancel.clone(), move |outcome| {
            let _ = tx.send(Event::Rendered { serial, outcome });
        });
        true
    }

    fn on_job_ready(&mut self, job: Arc<wire::JobSpec>, result: Result<Arc<LoadedJob>, String>, now: Instant) {
        let job_id = job.job_id.clone();
        self.loading.remove(&job_id);
        let waiting: Vec<u64> = self
            .slots
            .iter()
            .filter(|(_, s)| matches!(s.state, SlotState::WaitingScene) && s.unit.key.job_id == job_id)
            .map(|(&serial, _)| serial)
            .collect();
        match result {
            Ok(loaded) => {
                self.scenes.insert(loaded.clone());
                let mut other_spec = None;
                for serial in waiting {
                    let Some(slot) = self.slots.get(&serial) else { continue };
                    if *slot.unit.job == loaded.spec {
                        self.dispatch(serial, loaded.clone());
                    } else {
                        // The same job id with another spec (a restarted coordinator
                        // reusing ids while this load ran): load that one too.
                        other_spec = Some(slot.unit.job.clone());
                    }
                }
                if let Some(spec) = other_spec {
                    self.spawn_prepare(spec);
                }
            }
            Err(e) => {
                let waiting: Vec<u64> =
                    waiting.into_iter().filter(|s| self.slots.get(s).is_some_and(|s| s.unit.job == job)).collect();
                error!("job {job_id}: {e}; dropping its {} unit(s)", waiting.len());
                for serial in waiting {
                    self.slots.remove(&serial);
                }
                self.failed_jobs.push_back((job, now));
                while self.failed_jobs.len() > 64 {
                    self.failed_jobs.pop_front();
                }
            }
        }
    }

    fn on_rendered(&mut self, serial: u64, outcome: RenderOutcome) {
        let Some(slot) = self.slots.get_mut(&serial) else { return };
        if !matches!(slot.state, SlotState::InPool) {
            // Abandoned (or, impossibly, in another state): the result is not wanted.
            self.slots.remove(&serial);
            return;
        }
        match outcome {
            RenderOutcome::Done { acc, rays, elapsed } => {
                let result =
                    wire::result_to_proto(self.worker_id.unwrap_or(0), &slot.unit.key, slot.unit.samples, &acc, rays);
                debug!("unit {} rendered in {elapsed:.2?} ({rays} rays)", slot.unit.key);
                slot.state = SlotState::Finished { result: Box::new(result), submitting: false };
                slot.loaded = None;
            }
            RenderOutcome::Skipped => {
                self.slots.remove(&serial);
            }
            RenderOutcome::Panicked(m) => {
                error!("unit {}: the renderer panicked: {m}; dropping the unit", slot.unit.key);
                self.slots.remove(&serial);
            }
        }
    }

    fn on_submitted(
        &mut self,
        serial: u64,
        worker_id: u64,
        result: Result<proto::SubmitReply, RpcFailure>,
        now: Instant,
    ) {
        self.submits_in_flight = self.submits_in_flight.saturating_sub(1);
        let key = self.slots.get(&serial).map(|s| s.unit.key.clone());
        let key_text = key.as_ref().map_or_else(|| "?".to_string(), UnitKey::to_string);
        match result {
            Ok(reply) => {
                self.submit_backoff.reset();
                self.slots.remove(&serial);
                self.submitted += 1;
                if reply.accepted {
                    debug!("unit {key_text} submitted");
                } else {
                    debug!("unit {key_text} was already done elsewhere (duplicate ignored)");
                }
            }
            Err(RpcFailure::Rejected(status)) => {
                self.slots.remove(&serial);
                warn!(
                    "the coordinator rejected the result of unit {key_text} ({:?}): {}",
                    status.code(),
                    status.message()
                );
            }
            Err(e) => {
                // Kept, to be sent again (under a new worker id if need be).
                if let Some(SlotState::Finished { submitting, .. }) = self.slots.get_mut(&serial).map(|s| &mut s.state)
                {
                    *submitting = false;
                }
                if let RpcFailure::UnknownWorker(m) = &e {
                    self.lost_registration(worker_id, m, now);
                } else {
                    let mut d = self.submit_backoff.next_delay();
                    if self.draining() {
                        d = d.min(DRAIN_RETRY);
                    }
                    self.submit_next_at = self.submit_next_at.max(now + d);
                    warn!("cannot submit unit {key_text}: {e}; keeping it, retrying in {d:?}");
                }
            }
        }
    }

    fn on_heartbeat(&mut self, worker_id: u64, result: Result<proto::HeartbeatReply, RpcFailure>, now: Instant) {
        self.heartbeat.in_flight = false;
        match result {
            Ok(reply) => {
                if self.heartbeat_failures > 0 {
                    info!("heartbeats go through again");
                }
                self.heartbeat_failures = 0;
                for key in reply.abandon {
                    self.abandon(&wire::unit_key_from_proto(key));
                }
                if reply.shutdown {
                    self.begin_drain("the coordinator asked this worker to stop", SHUTDOWN_GRACE, now);
                }
            }
            Err(RpcFailure::UnknownWorker(m)) => self.lost_registration(worker_id, &m, now),
            Err(e) => {
                self.heartbeat_failures += 1;
                if self.heartbeat_failures == 1 {
                    warn!("heartbeat failed: {e}");
                } else {
                    debug!("heartbeat failed ({} in a row): {e}", self.heartbeat_failures);
                }
            }
        }
    }

    /// The coordinator no longer wants this unit: skip it if not started, discard its
    /// result if rendering, drop it if rendered but not yet being submitted.
    fn abandon(&mut self, key: &UnitKey) {
        let mut found = false;
        self.slots.retain(|_, s| {
            if !s.held() || s.unit.key != *key {
                return true;
            }
            found = true;
            match s.state {
                SlotState::WaitingScene | SlotState::Finished { submitting: false, .. } => false,
                SlotState::InPool => {
                    s.cancel.store(true, Ordering::Relaxed);
                    s.state = SlotState::Abandoned;
                    true
                }
                _ => true,
            }
        });
        if found {
            debug!("unit {key} abandoned at the coordinator's request");
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
