//! How the machine takes each event: replies and failures of the coordinator's calls,
//! loaded scenes, rendered units.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::anyhow;
use proto::domain::{JobSpec, UnitKey, WorkUnit};
use tracing::{debug, error, info, warn};

use super::{
    Action, DEFAULT_IDLE_WAIT, DRAIN_RETRY, Event, FAILED_JOB_MEMORY, Failure, Grant, Machine, Registration, Rendered,
    Renewal, SHUTDOWN_GRACE, Slot, SlotState,
};
use crate::asset_cache::LoadedJob;
use crate::executor::RenderOutcome;

impl Machine {
    /// Applies an event. An error only for what retrying cannot fix (the coordinator
    /// refusing this worker).
    pub fn handle(&mut self, event: Event, now: Instant) -> anyhow::Result<()> {
        let answered = match &event {
            Event::Registered(r) => !matches!(r, Err(Failure::Transport(_))),
            Event::Leased { result, .. } => !matches!(result, Err(Failure::Transport(_))),
            Event::Heartbeat { result, .. } => !matches!(result, Err(Failure::Transport(_))),
            Event::Submitted { result, .. } => !matches!(result, Err(Failure::Transport(_))),
            Event::JobReady { .. } | Event::Rendered { .. } => false,
        };
        if answered {
            self.last_contact = now;
        }
        match event {
            Event::Registered(result) => self.on_registered(result, now)?,
            Event::Leased { worker_id, result } => self.on_leased(worker_id, result, now),
            Event::Heartbeat { worker_id, result } => self.on_heartbeat(worker_id, result, now),
            Event::Submitted { serials, worker_id, result } => self.on_submitted(serials, worker_id, result, now),
            Event::JobReady { job, result } => self.on_job_ready(job, result, now),
            Event::Rendered { serial, outcome } => self.on_rendered(serial, outcome),
        }
        Ok(())
    }

    fn on_registered(&mut self, result: Result<Registration, Failure>, now: Instant) -> anyhow::Result<()> {
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
                    self.settings.coordinator, reply.worker_id, reply.lease_ms, self.heartbeat_every
                );
            }
            Err(Failure::Rejected { code, message }) => {
                return Err(anyhow!(
                    "the coordinator at {} refused to register this worker ({code}): {message}",
                    self.settings.coordinator
                ));
            }
            Err(e) => {
                let d = self.register.failed(now, self.drain.map(|_| DRAIN_RETRY));
                warn!("cannot register with {}: {e}; retrying in {d:?}", self.settings.coordinator);
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

    fn on_leased(&mut self, worker_id: u64, result: Result<Grant, Failure>, now: Instant) {
        match result {
            Ok(grant) => {
                if grant.shutdown {
                    self.lease.succeeded(now);
                    self.begin_drain("the coordinator asked this worker to stop", SHUTDOWN_GRACE, now);
                    return;
                }
                if self.draining() {
                    self.lease.succeeded(now);
                    return;
                }
                let offered = grant.units.len();
                let mut accepted = 0;
                for unit in grant.units {
                    accepted += usize::from(self.accept(unit, now));
                }
                for job in grant.prepare {
                    self.prepare_early(job, now);
                }
                let next = if accepted > 0 {
                    now
                } else {
                    let wait = match grant.retry_after_ms {
                        0 => DEFAULT_IDLE_WAIT,
                        ms => Duration::from_millis(u64::from(ms).min(60_000)),
                    };
                    debug!("lease: {offered} unit(s) offered, none taken; asking again in {wait:?}");
                    now + wait
                };
                self.lease.succeeded(next);
            }
            Err(Failure::UnknownWorker(m)) => {
                self.lease.succeeded(now);
                self.lost_registration(worker_id, &m, now);
            }
            Err(e) => {
                let d = self.lease.failed(now, None);
                warn!("lease failed: {e}; retrying in {d:?}");
            }
        }
    }

    /// Takes a leased unit: queues it for its scene or the render pool. False if it
    /// was dropped.
    fn accept(&mut self, unit: Result<WorkUnit, String>, now: Instant) -> bool {
        let unit = match unit {
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
                self.prepare(job);
            }
            true
        }
    }

    /// Loads a job the coordinator is still checking, unless it is loaded, loading or
    /// failed: its units will find the scene ready.
    fn prepare_early(&mut self, job: Arc<JobSpec>, now: Instant) {
        self.failed_jobs.retain(|(_, at)| now.duration_since(*at) < FAILED_JOB_MEMORY);
        let failed = self.failed_jobs.iter().any(|(j, _)| *j == job);
        if failed || self.loading.contains(&job.job_id) || self.loaded_job(&job).is_some() {
            return;
        }
        debug!("job {}: loading its scene while the coordinator checks it", job.job_id);
        self.prepare(job);
    }

    fn prepare(&mut self, job: Arc<JobSpec>) {
        self.loading.insert(job.job_id.clone());
        self.queued.push(Action::Prepare { job });
    }

    /// A job's loaded scene: from the cache, or from a unit that is using it.
    fn loaded_job(&mut self, job: &JobSpec) -> Option<Arc<LoadedJob>> {
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
        self.queued.push(Action::Render { serial, job: loaded, tile, samples, cancel: slot.cancel.clone() });
        true
    }

    fn on_job_ready(&mut self, job: Arc<JobSpec>, result: Result<Arc<LoadedJob>, String>, now: Instant) {
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
                    self.prepare(spec);
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
                debug!("unit {} rendered in {elapsed:.2?} ({rays} rays)", slot.unit.key);
                let seconds = elapsed.as_secs_f64();
                let unit = Rendered { key: slot.unit.key.clone(), samples: slot.unit.samples, acc, rays, seconds };
                slot.state = SlotState::Finished { unit: Arc::new(unit), submitting: false };
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
        serials: Vec<u64>,
        worker_id: u64,
        result: Result<Vec<Result<bool, String>>, Failure>,
        now: Instant,
    ) {
        self.submits_in_flight = self.submits_in_flight.saturating_sub(1);
        let key_text =
            |m: &Self, serial: &u64| m.slots.get(serial).map_or_else(|| "?".into(), |s| s.unit.key.to_string());
        match result {
            Ok(outcomes) => {
                self.submit_backoff.reset();
                // Merged results can make work at once (an adaptive tile's next batch
                // waits for its previous one): ask now, not after an idle answer's wait.
                if outcomes.iter().any(|o| matches!(o, Ok(true))) {
                    self.lease.hurry(now);
                }
                if outcomes.len() != serials.len() {
                    warn!("the coordinator answered {} results with {} outcomes", serials.len(), outcomes.len());
                }
                for (serial, outcome) in serials.iter().zip(outcomes.into_iter().chain(std::iter::repeat(Ok(false)))) {
                    let key = key_text(self, serial);
                    self.slots.remove(serial);
                    match outcome {
                        Ok(true) => {
                            self.submitted += 1;
                            debug!("unit {key} submitted");
                        }
                        Ok(false) => {
                            self.submitted += 1;
                            debug!("unit {key} was already done elsewhere (duplicate ignored)");
                        }
                        Err(why) => warn!("the coordinator refused the result of unit {key}: {why}"),
                    }
                }
            }
            Err(Failure::Rejected { code, message }) => {
                for serial in &serials {
                    warn!("the coordinator rejected the result of unit {} ({code}): {message}", key_text(self, serial));
                    self.slots.remove(serial);
                }
            }
            Err(e) => {
                // Kept, to be sent again (under a new worker id if need be).
                for serial in &serials {
                    if let Some(SlotState::Finished { submitting, .. }) =
                        self.slots.get_mut(serial).map(|s| &mut s.state)
                    {
                        *submitting = false;
                    }
                }
                if let Failure::UnknownWorker(m) = &e {
                    self.lost_registration(worker_id, m, now);
                } else {
                    let mut d = self.submit_backoff.next_delay();
                    if self.draining() {
                        d = d.min(DRAIN_RETRY);
                    }
                    self.submit_next_at = self.submit_next_at.max(now + d);
                    warn!("cannot submit {} result(s): {e}; keeping them, retrying in {d:?}", serials.len());
                }
            }
        }
    }

    fn on_heartbeat(&mut self, worker_id: u64, result: Result<Renewal, Failure>, now: Instant) {
        self.heartbeat.in_flight = false;
        match result {
            Ok(renewal) => {
                if self.heartbeat_failures > 0 {
                    info!("heartbeats go through again");
                }
                self.heartbeat_failures = 0;
                for key in renewal.abandon {
                    self.abandon(&key);
                }
                if renewal.shutdown {
                    self.begin_drain("the coordinator asked this worker to stop", SHUTDOWN_GRACE, now);
                }
            }
            Err(Failure::UnknownWorker(m)) => self.lost_registration(worker_id, &m, now),
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
