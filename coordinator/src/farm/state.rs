//! The farm's bookkeeping: registered workers, jobs in submission order, and the unit
//! operations workers ask for (lease, heartbeat, submit). Guarded by one mutex; every
//! operation is short (bookkeeping and exact integer merges, never rendering). What
//! happens to a job as a whole is [`super::lifecycle`]'s.

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;
use std::time::{Duration, Instant};

use proto::domain::JobSpec;
use tracer::scene::Scene;

use super::identities::Identities;
use super::job::{Applied, IdentityId, Job, JobPhase, Rejection, UnitId, UnitResult, UnitState, WorkerId};
use super::status::{JobStatus, status_of};
use super::verify::Policy;

/// Live workers one identity may register unless `serve --max-workers-per-identity`
/// says otherwise: a machine runs one worker with all its cores, so a few cover
/// restarts; more would let one certificate flood the farm with registrations.
pub const DEFAULT_WORKERS_PER_IDENTITY: u32 = 8;

/// Most units a worker may hold at once, per thread it registered with (it leases two
/// per thread, and may hold up to four more rendered but not yet sent).
const HELD_PER_THREAD: usize = 8;
/// Threads a worker is counted with at the most, whatever it claims.
const MAX_THREADS: u32 = 1024;

#[derive(Clone, Debug)]
pub struct FarmConfig {
    /// A lease lapses this long after its last renewal.
    pub lease: Duration,
    /// How often workers renew their leases.
    pub heartbeat: Duration,
    /// When the queue is empty, a unit out for longer than this is leased again to an
    /// idle worker (speculative execution).
    pub speculate_after: Duration,
    /// A worker not heard from for this long is forgotten (it registers again if it
    /// comes back), so a farm's memory follows its live workers, not its history.
    pub forget_worker_after: Duration,
    /// Most bytes one job's accumulations may take.
    pub max_job_bytes: u64,
    /// Largest uploaded file.
    pub max_upload_bytes: u64,
    /// Most bytes of uploaded files the store keeps.
    pub max_store_bytes: u64,
    /// Which results another identity renders again (none by default).
    pub verify: Policy,
    /// Most live workers one identity (a worker certificate, a token) may register.
    pub max_workers_per_identity: usize,
    /// Most jobs one user may have loading, queued or running.
    pub max_user_jobs: usize,
    /// Most bytes one user's running jobs may take together ([`Job::memory`]).
    pub max_user_bytes: u64,
    /// Most bytes all running jobs may take together.
    pub max_farm_bytes: u64,
}

impl Default for FarmConfig {
    fn default() -> Self {
        Self {
            lease: Duration::from_secs(10),
            heartbeat: Duration::from_secs(2),
            speculate_after: Duration::from_secs(10),
            forget_worker_after: Duration::from_secs(60),
            max_job_bytes: 8 << 30,
            max_upload_bytes: 4 << 30,
            max_store_bytes: 64 << 30,
            verify: Policy::default(),
            max_workers_per_identity: DEFAULT_WORKERS_PER_IDENTITY as usize,
            max_user_jobs: 16,
            max_user_bytes: 16 << 30,
            max_farm_bytes: 32 << 30,
        }
    }
}

#[derive(Clone, Debug)]
pub struct Worker {
    pub id: WorkerId,
    /// Who registered it (a certificate's fingerprint, or the token's caller): only they
    /// may act as this worker.
    pub identity: String,
    /// The identity it is trusted, checked and banned as (see `identities`).
    pub trust: IdentityId,
    pub hostname: String,
    pub threads: u32,
    pub last_seen: Instant,
    pub units_done: u64,
}

/// A job's spec as the workers receive it, plus its loaded scene (for the in-process
/// executor).
pub struct JobEntry {
    pub job: Job,
    pub spec: Arc<JobSpec>,
    pub scene: Option<Arc<Scene>>,
    /// What the image's EXR header records, once the scene has loaded.
    pub info: Option<tracer::output::RenderInfo>,
    /// Where the finished image was stored, when the job's sums have left memory.
    pub stored: Option<std::path::PathBuf>,
    /// How many warnings its scene's first load gave: a later load (to decide a dispute)
    /// that gives more did not read the same scene, and is not trusted.
    pub scene_warnings: usize,
    /// A queued frame's checkpoint, for when it starts.
    pub pending_restore: Option<super::job::Restored>,
    /// What its running takes in memory ([`Job::memory`]), once its scene has loaded.
    pub bytes: u64,
}

impl JobEntry {
    /// The header record of the image as it is now (render time so far).
    pub fn render_info(&self) -> Option<tracer::output::RenderInfo> {
        let mut info = self.info.clone()?;
        info.seconds = self.job.elapsed().as_secs_f64();
        info.spp = self.job.spp;
        Some(info)
    }
}

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum FarmError {
    #[error("unknown worker {0}: register again")]
    UnknownWorker(WorkerId),
    #[error("unknown job {0}")]
    UnknownJob(String),
    /// A request that can never succeed as it is.
    #[error("{0}")]
    Invalid(String),
    /// A job's file that is not in the store.
    #[error("{0}")]
    NotUploaded(String),
    #[error(transparent)]
    Rejected(#[from] Rejection),
    /// The caller may not do this (another's worker id or job).
    #[error("{0}")]
    Forbidden(String),
    /// A limit was reached (registrations of one identity).
    #[error("{0}")]
    Exhausted(String),
}

/// What [`Farm::update_job`] changes (`None`: as it is).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct JobChange {
    pub priority: Option<u32>,
    pub paused: Option<bool>,
    /// A larger spp: more batches for every tile.
    pub spp: Option<u32>,
}

#[derive(Default)]
pub struct Farm {
    pub config: FarmConfig,
    pub workers: BTreeMap<WorkerId, Worker>,
    pub(super) next_worker: WorkerId,
    /// Who the workers are: what is trusted, checked and banned (see `identities`).
    pub identities: Identities,
    /// In submission order (which breaks ties of the fair share).
    pub jobs: Vec<JobEntry>,
    index: HashMap<String, usize>,
    next_job: u64,
    /// Tell workers to stop (the local render is over).
    pub shutting_down: bool,
    /// When silent workers were last looked for.
    last_worker_sweep: Option<Instant>,
    /// How running jobs share the workers.
    fair: super::schedule::FairShare,
    /// Unit events the farm counts itself, and those of jobs no longer listed.
    counters: super::meters::UnitCounters,
}

/// A disputed unit for the coordinator to render itself ([`Farm::take_disputes`]).
pub struct Dispute {
    pub job: String,
    /// The job's scene, when the coordinator keeps it (else it is loaded for this).
    pub scene: Option<Arc<Scene>>,
    /// Warnings of the scene's first load ([`JobEntry::scene_warnings`]).
    pub scene_warnings: usize,
    pub integrator: tracer::integrator::Integrator,
    pub unit: UnitId,
    pub tile: tracer::film::Tile,
    pub samples: tracer::film::SampleRange,
}

/// A unit handed out by [`Farm::lease`].
pub struct Leased {
    pub spec: Arc<JobSpec>,
    pub unit: UnitId,
    pub tile: tracer::film::Tile,
    pub samples: tracer::film::SampleRange,
}

impl Farm {
    pub fn new(config: FarmConfig) -> Self {
        Self { config, next_worker: first_worker_id(), next_job: 1, ..Default::default() }
    }

    /// Creates a job in the loading phase; returns its id. A job restored from a
    /// checkpoint keeps its id (`spec.job_id`) when it is free.
    pub fn add_job(&mut self, name: String, owner: Option<String>, mut spec: JobSpec) -> String {
        let wanted = spec.job_id.strip_prefix("job-").and_then(|n| n.parse::<u64>().ok());
        let id = match wanted {
            Some(n) if !self.index.contains_key(&spec.job_id) => {
                self.next_job = self.next_job.max(n + 1);
                spec.job_id.clone()
            }
            _ => {
                let id = format!("job-{}", self.next_job);
                self.next_job += 1;
                id
            }
        };
        spec.job_id = id.clone();
        self.index.insert(id.clone(), self.jobs.len());
        let mut job = Job::loading(id.clone(), name);
        job.owner = owner;
        // A frame of a group waits its turn (`due_frames`).
        job.group = spec.group.clone();
        if job.group.is_some() {
            job.phase = super::job::JobPhase::Queued;
        }
        let entry = JobEntry {
            job,
            spec: Arc::new(spec),
            scene: None,
            info: None,
            stored: None,
            scene_warnings: 0,
            pending_restore: None,
            bytes: 0,
        };
        self.jobs.push(entry);
        id
    }

    /// Changes a running or loading job's priority or pauses it, or raises a running
    /// job's spp (within `max_job_bytes` and the unit limit). Pausing takes effect at unit
    /// boundaries: units out finish and merge.
    pub fn update_job(&mut self, job: &str, change: &JobChange) -> Result<(), FarmError> {
        let max_bytes = self.config.max_job_bytes;
        let e = self.entry_mut(job)?;
        let j = &mut e.job;
        if j.phase.is_final() {
            return Err(FarmError::Invalid(format!("job {job} has ended; there is nothing to change")));
        }
        let priority = match change.priority {
            Some(0) => return Err(FarmError::Invalid("priority 0: priorities run from 1".into())),
            Some(p) => Some(super::schedule::priority(p).map_err(FarmError::Invalid)?),
            None => None,
        };
        if let Some(spp) = change.spp {
            if j.phase != super::job::JobPhase::Running {
                return Err(FarmError::Invalid(format!("job {job} is still loading; raise its spp once it runs")));
            }
            if spp <= j.spp {
                return Err(FarmError::Invalid(format!("spp {spp}: the job already renders {} spp", j.spp)));
            }
            if !j.tile_spp.is_empty() {
                return Err(FarmError::Invalid(format!("job {job} renders an spp map; its spp cannot be raised")));
            }
            super::job::Job::check_size((j.width, j.height), spp, (j.tile_size, j.batch_spp), j.layers, max_bytes)
                .map_err(FarmError::Invalid)?;
            j.extend_spp(spp);
        }
        if let Some(p) = priority {
            j.share.priority = p;
        }
        if let Some(paused) = change.paused {
            j.share.paused = paused;
        }
        Ok(())
    }

    /// The queued frames of job groups that may start now, marked as loading
    /// ([`super::groups::due_frames`]).
    pub fn due_frames(&mut self) -> Vec<String> {
        super::groups::due_frames(self.jobs.iter_mut().map(|e| &mut e.job))
    }

    /// Job ids up to `n` are taken (by finished jobs whose images are stored).
    pub fn reserve_job_ids_through(&mut self, n: u64) {
        self.next_job = self.next_job.max(n + 1);
    }

    /// Removes jobs for which `gone` is true, keeping the others' order.
    pub fn remove_jobs(&mut self, gone: impl Fn(&JobEntry) -> bool) -> Vec<String> {
        let removed: Vec<String> = self.jobs.iter().filter(|e| gone(e)).map(|e| e.job.id.clone()).collect();
        for e in self.jobs.iter().filter(|e| gone(e)) {
            self.counters.add(&super::meters::UnitCounters::of_job(&e.job));
        }
        if !removed.is_empty() {
            self.jobs.retain(|e| !gone(e));
            self.index = self.jobs.iter().enumerate().map(|(i, e)| (e.job.id.clone(), i)).collect();
        }
        removed
    }

    pub fn entry(&self, job: &str) -> Result<&JobEntry, FarmError> {
        self.index.get(job).map(|&i| &self.jobs[i]).ok_or_else(|| FarmError::UnknownJob(job.to_string()))
    }

    pub fn entry_mut(&mut self, job: &str) -> Result<&mut JobEntry, FarmError> {
        match self.index.get(job) {
            Some(&i) => Ok(&mut self.jobs[i]),
            None => Err(FarmError::UnknownJob(job.to_string())),
        }
    }

    /// Up to `max` units for `worker`: between running jobs by weighted fair share
    /// (`schedule`), in progressive order within each.
    pub fn lease(&mut self, worker: WorkerId, max: usize, now: Instant) -> Result<Vec<Leased>, FarmError> {
        let by = self.touch(worker, now)?;
        self.reap(now);
        let deadline = now + self.config.lease;
        let siblings: Vec<WorkerId> = self.workers.values().filter(|w| w.trust == by.identity).map(|w| w.id).collect();
        // A worker leases twice its threads and may hold as many again rendered but not
        // yet sent: more than that is hoarding.
        let threads = self.workers.get(&worker).map_or(1, |w| w.threads.clamp(1, MAX_THREADS)) as usize;
        let held: usize = self.jobs.iter().map(|e| e.job.held_by(worker)).sum();
        let max = max.min((HELD_PER_THREAD * threads).saturating_sub(held)).min(self.room_in_share(by, now));
        let mut out = Vec::new();
        // Unit by unit, to the running job with the least service for its priority.
        let mut dry = vec![false; self.jobs.len()];
        while out.len() < max {
            let eligible = self.eligible(&dry);
            let running = self.jobs.iter_mut().enumerate().filter(|(k, _)| eligible[*k]);
            let Some(k) = self.fair.pick(running.map(|(k, e)| (k, &mut e.job.share))) else { break };
            let e = &mut self.jobs[k];
            match e.job.lease_next_among(by, &siblings, now, deadline, self.config.speculate_after) {
                Some(unit) => {
                    self.fair.served(&mut e.job.share);
                    self.counters.leased += 1;
                    let u = &e.job.units[unit as usize];
                    out.push(Leased { spec: Arc::clone(&e.spec), unit, tile: u.tile, samples: u.samples });
                }
                None => dry[k] = true,
            }
        }
        Ok(out)
    }

    /// Which jobs may be given a unit now: those running and not paused, with units left
    /// (not `dry`), and of a job group's only the first ([`super::groups::first_frames`]).
    fn eligible(&self, dry: &[bool]) -> Vec<bool> {
        let running = |k: usize, j: &Job| !dry[k] && j.phase == super::job::JobPhase::Running && !j.share.paused;
        super::groups::first_frames(self.jobs.iter().enumerate().map(|(k, e)| (&e.job, running(k, &e.job))))
    }

    /// Jobs still loading (their scenes being checked), oldest first, at most `max`:
    /// what workers may load in the meantime.
    pub fn loading(&self, max: usize) -> Vec<Arc<JobSpec>> {
        let loading = self.jobs.iter().filter(|e| e.job.phase == super::job::JobPhase::Loading);
        loading.take(max).map(|e| Arc::clone(&e.spec)).collect()
    }

    /// Renews `worker`'s leases; returns the units it should abandon.
    pub fn heartbeat(
        &mut self,
        worker: WorkerId,
        held: &[(String, UnitId)],
        now: Instant,
    ) -> Result<Vec<(String, UnitId)>, FarmError> {
        self.touch(worker, now)?;
        let deadline = now + self.config.lease;
        let mut abandon = Vec::new();
        for (job, unit) in held {
            let keep = match self.index.get(job) {
                Some(&i) => self.jobs[i].job.renew(worker, *unit, deadline),
                None => false,
            };
            if !keep {
                abandon.push((job.clone(), *unit));
            }
        }
        Ok(abandon)
    }

    /// Merges `worker`'s result into its job. Also says whether this result finished
    /// the job (the lifecycle's to act on).
    pub fn submit(
        &mut self,
        worker: WorkerId,
        job: &str,
        result: &UnitResult,
        now: Instant,
    ) -> Result<(Applied, bool), FarmError> {
        let by = self.touch(worker, now)?;
        let record = self.identities.get(by.identity).map_or(0, |i| i.answers);
        let check = self.config.verify.must_check(record, job, result.unit);
        let entry = self.entry_mut(job)?;
        let was_running = entry.job.phase == JobPhase::Running;
        let primary = entry.job.units.get(result.unit as usize).and_then(|u| match u.state {
            UnitState::Leased { worker: p, .. } if p != worker => Some(p),
            _ => None,
        });
        let applied = match entry.job.apply_at(by, result, now, check) {
            Ok(a) => a,
            Err(e) => {
                self.counters.rejected += 1;
                if let Rejection::Malformed { unit, .. } = &e {
                    let unit = *unit;
                    self.entry_mut(job)?.job.release(worker, unit, now);
                    self.refused(by, job, unit);
                }
                return Err(e.into());
            }
        };
        let caught = entry.job.take_caught();
        if let Some(w) = self.workers.get_mut(&worker) {
            w.units_done += u64::from(applied == Applied::Merged);
        }
        if let Some(i) = self.identities.get_mut(by.identity) {
            i.answers += u64::from(applied.accepted());
            i.strikes = i.strikes.saturating_sub(u32::from(applied.accepted()));
        }
        // Another identity finished a unit that this worker's lease still held: a strike
        // against the holder's identity (see `room_in_share`).
        let beaten = primary.filter(|_| applied == Applied::Merged).and_then(|p| self.workers.get(&p)).map(|w| w.trust);
        if let Some(i) = beaten.filter(|&t| t != by.identity).and_then(|t| self.identities.get_mut(t)) {
            i.strikes += 1;
        }
        for liar in caught {
            self.ban(liar, job, result.unit);
        }
        let finished = was_running && self.entry(job)?.job.phase == JobPhase::Done;
        Ok((applied, finished))
    }

    /// Disputed units no live worker can settle, with what the coordinator needs to
    /// render them itself: (job, its scene and integrator, the unit).
    pub fn take_disputes(&mut self, now: Instant) -> Vec<Dispute> {
        if !self.config.verify.enabled() {
            return Vec::new();
        }
        let live = self.settling_identities(now);
        let mut out = Vec::new();
        for e in &mut self.jobs {
            for id in e.job.disputes_nobody_can_settle(&live) {
                let u = &e.job.units[id as usize];
                out.push(Dispute {
                    job: e.job.id.clone(),
                    scene: e.scene.clone(),
                    scene_warnings: e.scene_warnings,
                    integrator: e.spec.integrator,
                    unit: id,
                    tile: u.tile,
                    samples: u.samples,
                });
            }
        }
        out
    }

    /// The coordinator's own render of a disputed unit arrived (or, with `None`, failed).
    /// Also says whether it finished the job (the lifecycle's to act on, as for
    /// [`Farm::submit`]).
    pub fn arbitrated(&mut self, job: &str, unit: UnitId, result: Option<&UnitResult>, now: Instant) -> bool {
        let Ok(entry) = self.entry_mut(job) else { return false };
        let Some(r) = result else {
            entry.job.arbitration_failed(unit);
            return false;
        };
        let was_running = entry.job.phase == JobPhase::Running;
        if let Err(e) = entry.job.arbitrate(r, now) {
            tracing::warn!(%job, unit, "the coordinator's render of a disputed unit was refused: {e}");
        }
        for liar in entry.job.take_caught() {
            self.ban(liar, job, unit);
        }
        was_running && self.entry(job).is_ok_and(|e| e.job.phase == JobPhase::Done)
    }

    /// Returns lapsed leases of every job to its queue, and (at most once a second)
    /// forgets workers silent for longer than `forget_worker_after`.
    pub fn reap(&mut self, now: Instant) {
        if self.last_worker_sweep.is_none_or(|t| now.duration_since(t) >= Duration::from_secs(1)) {
            self.last_worker_sweep = Some(now);
            let grace = self.config.forget_worker_after;
            let before = self.workers.len();
            self.workers.retain(|_, w| now.saturating_duration_since(w.last_seen) < grace);
            if self.workers.len() < before {
                tracing::info!(workers = before - self.workers.len(), "silent workers forgotten");
            }
        }
        for e in &mut self.jobs {
            let n = e.job.reap_expired(now);
            self.counters.lapsed += n as u64;
            if n > 0 {
                tracing::warn!(job = %e.job.id, units = n, "leases lapsed; units re-queued");
            }
            // A lapsed lease counts against its identity, as a unit others finished does.
            for w in e.job.take_lapsed() {
                let trust = self.workers.get(&w).map(|w| w.trust);
                if let Some(i) = trust.and_then(|t| self.identities.get_mut(t)) {
                    i.strikes += 1;
                }
            }
        }
    }

    /// Unit events since the farm started, over every job it has held.
    pub fn unit_counters(&self) -> super::meters::UnitCounters {
        let mut c = self.counters;
        for e in &self.jobs {
            c.add(&super::meters::UnitCounters::of_job(&e.job));
        }
        c
    }

    pub fn status(&self, job: &str, now: Instant) -> Result<JobStatus, FarmError> {
        Ok(status_of(&self.entry(job)?.job, self.live_workers(now)))
    }

    /// Every listed job's status, in submission order.
    pub fn statuses(&self, now: Instant) -> Vec<JobStatus> {
        self.statuses_of(now, |_| true)
    }

    /// The statuses of the jobs whose owner `visible` accepts.
    pub fn statuses_of(&self, now: Instant, visible: impl Fn(Option<&str>) -> bool) -> Vec<JobStatus> {
        let workers = self.live_workers(now);
        self.jobs.iter().filter(|e| visible(e.job.owner.as_deref())).map(|e| status_of(&e.job, workers)).collect()
    }
}

/// Worker ids start at this coordinator's start time in microseconds since 1970, so that
/// a restarted coordinator never hands out an id that a worker of its previous run still
/// uses (that worker's calls would pass as the new one's).
fn first_worker_id() -> WorkerId {
    let since_epoch = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
    (since_epoch.as_micros() as WorkerId).max(1)
}

#[cfg(test)]
pub(super) mod tests;
