//! The worker's state machine: events in, actions out, no I/O. Register, lease,
//! prepare scenes, render, submit, heartbeat, abandon, stop — every decision about
//! what to do next is made here, from the events the shell reports (a reply, a failure,
//! a loaded scene, a rendered unit) and the time it passes in; the shell
//! ([`crate::shell`]) performs the [`Action`]s. So the whole protocol is tested without
//! a network, a clock or a render thread ([`tests`]).
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

pub mod backoff;
mod events;
mod ops;
#[cfg(test)]
mod tests;

use std::collections::{BTreeMap, HashSet, VecDeque};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use proto::domain::{JobSpec, UnitKey, WorkUnit};
use tracer::film::{Accumulation, SampleRange, Tile};
use tracing::info;

use crate::asset_cache::{LoadedJob, SceneCache};
use crate::executor::RenderOutcome;
use backoff::Backoff;
use ops::Op;

/// How long finished results may take to reach the coordinator after a signal.
pub const SIGNAL_GRACE: Duration = Duration::from_secs(2);
/// ... and after the coordinator asked the worker to stop.
const SHUTDOWN_GRACE: Duration = Duration::from_secs(5);
/// Retry interval while stopping, whatever the backoff has grown to.
const DRAIN_RETRY: Duration = Duration::from_millis(250);
/// Wait before asking again after a lease reply without usable units and no hint.
const DEFAULT_IDLE_WAIT: Duration = Duration::from_millis(500);
/// Units of a job whose scene failed to load are dropped for this long.
const FAILED_JOB_MEMORY: Duration = Duration::from_secs(30);
/// Submissions in flight at once (HTTP/2 multiplexes them on one connection); each
/// carries every result ready when it starts, within the message size.
const MAX_SUBMITS_IN_FLIGHT: usize = 4;
/// Room kept free in a submission's message for the call's own fields.
const SUBMIT_MARGIN_BYTES: usize = 64 * 1024;
/// Loaded scenes kept beyond those in use.
const SCENE_CACHE_JOBS: usize = 2;

pub use crate::failure::Failure;

/// The coordinator's answer to a registration.
#[derive(Clone, Debug)]
pub struct Registration {
    pub worker_id: u64,
    pub lease_ms: u32,
    pub heartbeat_ms: u32,
}

/// The coordinator's answer to a lease request: units (each checked by the wire
/// mapping, or why it is malformed), when to ask again, whether to stop, and jobs whose
/// scenes it is still checking (to load now, before their units come).
#[derive(Debug, Default)]
pub struct Grant {
    pub units: Vec<Result<WorkUnit, String>>,
    pub retry_after_ms: u32,
    pub shutdown: bool,
    pub prepare: Vec<Arc<JobSpec>>,
}

/// The coordinator's answer to a heartbeat.
#[derive(Debug, Default)]
pub struct Renewal {
    pub abandon: Vec<UnitKey>,
    pub shutdown: bool,
}

/// What the shell reports: completions of work done outside the machine.
pub enum Event {
    Registered(Result<Registration, Failure>),
    Leased {
        worker_id: u64,
        result: Result<Grant, Failure>,
    },
    Heartbeat {
        worker_id: u64,
        result: Result<Renewal, Failure>,
    },
    /// Results were sent (`serials`, in order): for each, whether the coordinator merged
    /// it (false: a duplicate) or why it refused it.
    Submitted {
        serials: Vec<u64>,
        worker_id: u64,
        result: Result<Vec<Result<bool, String>>, Failure>,
    },
    JobReady {
        job: Arc<JobSpec>,
        result: Result<Arc<LoadedJob>, String>,
    },
    Rendered {
        serial: u64,
        outcome: RenderOutcome,
    },
}

/// A rendered unit, ready to send.
#[derive(Debug)]
pub struct Rendered {
    pub key: UnitKey,
    pub samples: SampleRange,
    pub acc: Accumulation,
    pub rays: u64,
    /// How long it took to render (not to load its scene).
    pub seconds: f64,
}

/// What the machine asks the shell to do. Each call's outcome comes back as an
/// [`Event`].
pub enum Action {
    Register,
    Heartbeat {
        worker_id: u64,
        held: Vec<UnitKey>,
    },
    Lease {
        worker_id: u64,
        max_units: u32,
    },
    /// Send these results in one call (`serials` name them in the reply's event).
    Submit {
        serials: Vec<u64>,
        worker_id: u64,
        units: Vec<Arc<Rendered>>,
    },
    /// Download the job's files and load its scene.
    Prepare {
        job: Arc<JobSpec>,
    },
    /// Render a unit; `cancel` set before a thread starts it skips it.
    Render {
        serial: u64,
        job: Arc<LoadedJob>,
        tile: Tile,
        samples: SampleRange,
        cancel: Arc<AtomicBool>,
    },
}

impl std::fmt::Debug for Action {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Action::Register => write!(f, "Register"),
            Action::Heartbeat { worker_id, held } => write!(f, "Heartbeat({worker_id}, {} held)", held.len()),
            Action::Lease { worker_id, max_units } => write!(f, "Lease({worker_id}, {max_units})"),
            Action::Submit { serials, .. } => write!(f, "Submit({serials:?})"),
            Action::Prepare { job } => write!(f, "Prepare({})", job.job_id),
            Action::Render { serial, tile, samples, .. } => write!(f, "Render(#{serial} {tile:?} {samples:?})"),
        }
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
    /// Rendered; held until the coordinator takes or refuses it.
    Finished { unit: Arc<Rendered>, submitting: bool },
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

    fn finished(&self) -> bool {
        matches!(self.state, SlotState::Finished { .. })
    }

    fn unsent(&self) -> bool {
        matches!(self.state, SlotState::Finished { submitting: false, .. })
    }
}

/// The machine's settings.
pub struct Settings {
    /// The coordinator's address, for messages.
    pub coordinator: String,
    pub threads: usize,
    pub max_backoff: Duration,
    /// Stop once the coordinator has been unreachable this long (`None`: never).
    pub give_up_after: Option<Duration>,
}

pub struct Machine {
    settings: Settings,
    /// Actions decided while handling events, handed out by [`Machine::actions`].
    queued: Vec<Action>,

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
    failed_jobs: VecDeque<(Arc<JobSpec>, Instant)>,
    /// Stopping: the time by which the worker exits.
    drain: Option<Instant>,
    submitted: u64,
    /// The last time the coordinator answered at all.
    last_contact: Instant,
}

impl Machine {
    pub fn new(settings: Settings, now: Instant) -> Self {
        let max_backoff = settings.max_backoff;
        Self {
            settings,
            queued: Vec::new(),
            worker_id: None,
            heartbeat_every: Duration::from_secs(1),
            register: Op::new(now, max_backoff),
            lease: Op::new(now, max_backoff),
            heartbeat: Op::new(now, max_backoff),
            submits_in_flight: 0,
            submit_next_at: now,
            submit_backoff: Backoff::new(max_backoff),
            heartbeat_failures: 0,
            slots: BTreeMap::new(),
            next_serial: 0,
            loading: HashSet::new(),
            scenes: SceneCache::new(SCENE_CACHE_JOBS),
            failed_jobs: VecDeque::new(),
            drain: None,
            submitted: 0,
            last_contact: now,
        }
    }

    /// Results the coordinator has taken.
    pub fn submitted(&self) -> u64 {
        self.submitted
    }

    /// Rendered results not (yet) taken by the coordinator.
    pub fn unsent(&self) -> usize {
        self.slots.values().filter(|s| s.finished()).count()
    }

    fn draining(&self) -> bool {
        self.drain.is_some()
    }

    fn has_finished(&self) -> bool {
        self.slots.values().any(Slot::finished)
    }

    /// How many more units to lease: fill the prefetch window of `2 × threads`, unless
    /// results are piling up unsent.
    fn lease_want(&self) -> usize {
        let threads = self.settings.threads;
        let pending = self.slots.values().filter(|s| s.pending_render()).count();
        if self.unsent() >= 4 * threads { 0 } else { (2 * threads).saturating_sub(pending) }
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
        self.worker_id.is_some()
            && self.submits_in_flight < MAX_SUBMITS_IN_FLIGHT
            && self.slots.values().any(Slot::unsent)
    }

    /// Everything to start now: what handling events decided, then every call whose
    /// time has come.
    pub fn actions(&mut self, now: Instant) -> Vec<Action> {
        if let Some(limit) = self.settings.give_up_after
            && now.duration_since(self.last_contact) > limit
            && !self.draining()
        {
            tracing::warn!("the coordinator has been unreachable for {limit:?}: giving up as --give-up-after-ms asks");
            self.begin_drain("coordinator gone", SIGNAL_GRACE, now);
        }
        let mut out = std::mem::take(&mut self.queued);
        if self.register_wanted() && self.register.due(now) {
            self.register.in_flight = true;
            out.push(Action::Register);
        }
        if self.heartbeat_wanted()
            && self.heartbeat.due(now)
            && let Some(worker_id) = self.worker_id
        {
            self.heartbeat.in_flight = true;
            self.heartbeat.next_at = now + self.heartbeat_every;
            let held = self.slots.values().filter(|s| s.held()).map(|s| s.unit.key.clone()).collect();
            out.push(Action::Heartbeat { worker_id, held });
        }
        if self.lease_wanted()
            && self.lease.due(now)
            && let Some(worker_id) = self.worker_id
        {
            self.lease.in_flight = true;
            out.push(Action::Lease { worker_id, max_units: u32::try_from(self.lease_want()).unwrap_or(u32::MAX) });
        }
        while self.submit_wanted() && now >= self.submit_next_at {
            let Some(worker_id) = self.worker_id else { break };
            let (serials, units) = self.next_batch();
            self.submits_in_flight += 1;
            out.push(Action::Submit { serials, worker_id, units });
        }
        out
    }

    /// The unsent results for one submission, marked as being sent: as many as fit in a
    /// message, at least one.
    fn next_batch(&mut self) -> (Vec<u64>, Vec<Arc<Rendered>>) {
        let budget = proto::MAX_MESSAGE_BYTES - SUBMIT_MARGIN_BYTES;
        let (mut serials, mut units, mut bytes) = (Vec::new(), Vec::new(), 0);
        for (&serial, slot) in &mut self.slots {
            let SlotState::Finished { unit, submitting: submitting @ false } = &mut slot.state else { continue };
            let size = proto::wire::result_bytes_bound(unit.acc.tile, unit.acc.has_layers());
            if !units.is_empty() && (bytes + size > budget || units.len() == proto::MAX_RESULTS_PER_CALL) {
                break;
            }
            *submitting = true;
            bytes += size;
            serials.push(serial);
            units.push(Arc::clone(unit));
        }
        (serials, units)
    }

    /// The earliest future time at which something is due (the shell sleeps until
    /// then, or until an event arrives).
    pub fn next_deadline(&self, now: Instant) -> Option<Instant> {
        let candidates = [
            self.drain,
            self.settings.give_up_after.filter(|_| !self.draining()).map(|g| self.last_contact + g),
            self.register_wanted().then_some(self.register.next_at),
            self.heartbeat_wanted().then_some(self.heartbeat.next_at),
            self.lease_wanted().then_some(self.lease.next_at),
            self.submit_wanted().then_some(self.submit_next_at),
        ];
        candidates.into_iter().flatten().filter(|&t| t > now).min()
    }

    /// Stopping, and either out of time or with nothing left to submit?
    pub fn done(&self, now: Instant) -> bool {
        match self.drain {
            None => false,
            Some(deadline) => now >= deadline || (!self.has_finished() && self.submits_in_flight == 0),
        }
    }

    /// Stop taking work: drop what has not been rendered, keep submitting what has,
    /// for at most `grace`.
    pub fn begin_drain(&mut self, why: &str, grace: Duration, now: Instant) {
        let deadline = now + grace;
        match &mut self.drain {
            Some(d) => *d = (*d).min(deadline),
            None => {
                info!("{why}: stopping (submitting {} finished result(s), dropping unrendered units)", self.unsent());
                self.drain = Some(deadline);
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
}
