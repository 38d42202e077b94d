//! The farm's workers: registering them under their identity (within its limit),
//! checking that a call comes from the identity that registered the worker, which are
//! live, and what happens to an identity that lies or sends malformed results.

use std::time::Instant;

use super::identities::MAX_REFUSED;
use super::ids::{By, IdentityId, UnitId, WorkerId};
use super::job::JobPhase;
use super::state::{Farm, FarmError, Worker};

/// Most warnings a job keeps (its scene's, then events such as a ban).
const MAX_EVENTS: usize = 40;
/// Units an identity may always hold, whatever its share (see `Farm::room_in_share`).
const MIN_SHARE: usize = 8;
/// Strikes (units others finished while it held them, lapsed leases) past which an
/// identity holds at most [`MIN_SHARE`] units.
const MAX_STRIKES: u32 = 8;

impl Farm {
    /// Registers a worker of the farm's own (in-process, tests): an identity of its own.
    pub fn register(&mut self, hostname: String, threads: u32, now: Instant) -> WorkerId {
        let trust = self.identities.anonymous(now);
        self.add_worker("admin".into(), trust, hostname, threads, now)
    }

    /// Registers a worker for `identity` (None: a farm without access control, where
    /// each registration is an identity of its own). A banned identity is refused, and
    /// a `capped` one (all but admins, who may do anything anyway: a local render's
    /// workers) may hold at most `max_workers_per_identity` live registrations.
    pub fn register_as(
        &mut self,
        identity: Option<&str>,
        capped: bool,
        hostname: String,
        threads: u32,
        now: Instant,
    ) -> Result<WorkerId, FarmError> {
        self.reap(now);
        let Some(name) = identity else { return Ok(self.register(hostname, threads, now)) };
        let trust = self.identities.named(name, now);
        if let Some(ban) = &trust.banned {
            return Err(FarmError::Forbidden(format!(
                "this identity is banned ({}); an admin may lift the ban with `coordinator unban {}`",
                ban.reason, trust.name
            )));
        }
        let trust = trust.id;
        let held = self.workers.values().filter(|w| w.trust == trust).count();
        let most = self.config.max_workers_per_identity;
        if capped && held >= most {
            return Err(FarmError::Exhausted(format!(
                "this identity already has {held} workers registered, the most one may have \
                 (serve --max-workers-per-identity {most}); give each machine its own certificate"
            )));
        }
        Ok(self.add_worker(name.to_string(), trust, hostname, threads, now))
    }

    fn add_worker(
        &mut self,
        identity: String,
        trust: IdentityId,
        hostname: String,
        threads: u32,
        now: Instant,
    ) -> WorkerId {
        let id = self.next_worker;
        self.next_worker += 1;
        let w = Worker { id, identity, trust, hostname, threads, last_seen: now, units_done: 0 };
        self.workers.insert(id, w);
        let workers = &self.workers;
        self.identities.forget_idle(|i| workers.values().any(|w| w.trust == i));
        id
    }

    /// Is `identity` the one that registered `worker`? (An unknown worker is left to
    /// the call itself, which tells it to register again.)
    pub fn check_identity(&self, worker: WorkerId, identity: &str) -> Result<(), FarmError> {
        match self.workers.get(&worker) {
            Some(w) if w.identity != identity => {
                Err(FarmError::Forbidden(format!("worker {worker} was registered by another identity")))
            }
            _ => Ok(()),
        }
    }

    /// Whether `w` is quarantined: its identity is banned, so it gets no more work (and
    /// what the identity returned unconfirmed was thrown away).
    pub fn quarantined(&self, w: &Worker) -> bool {
        self.identities.is_banned(w.trust)
    }

    /// Marks `worker` seen; says who it is, or why it may do nothing.
    pub(super) fn touch(&mut self, worker: WorkerId, now: Instant) -> Result<By, FarmError> {
        let w = self.workers.get_mut(&worker).ok_or(FarmError::UnknownWorker(worker))?;
        w.last_seen = now;
        let trust = w.trust;
        if self.identities.is_banned(trust) {
            return Err(FarmError::Forbidden(format!(
                "worker {worker} is quarantined: its identity returned a result that differed from other \
                 identities' renders of the same unit, or malformed results"
            )));
        }
        Ok(By { worker, identity: trust })
    }

    /// Workers seen within three lease periods, and not quarantined.
    pub(super) fn live(&self, now: Instant) -> impl Iterator<Item = &Worker> {
        let grace = 3 * self.config.lease;
        self.workers
            .values()
            .filter(move |w| !self.quarantined(w) && now.saturating_duration_since(w.last_seen) < grace)
    }

    /// How many workers are [live](Farm::live).
    pub fn live_workers(&self, now: Instant) -> usize {
        self.live(now).count()
    }

    /// The live identities that could still settle a check: all but those past
    /// [`MAX_STRIKES`] (a hoarder leases nothing it would answer).
    pub(super) fn settling_identities(&self, now: Instant) -> Vec<IdentityId> {
        let mut live = self.live_identities(now);
        live.retain(|&i| self.identities.get(i).is_none_or(|i| i.strikes < MAX_STRIKES));
        live
    }

    /// The identities of the live workers, each once.
    pub(super) fn live_identities(&self, now: Instant) -> Vec<IdentityId> {
        let mut ids: Vec<IdentityId> = self.live(now).map(|w| w.trust).collect();
        ids.sort_unstable();
        ids.dedup();
        ids
    }

    /// How many more units the identity of `by` may hold: with several identities live,
    /// each holds at most an even share of the running jobs' open units (queued or out;
    /// at least [`MIN_SHARE`]), so that an identity that leases units and never returns
    /// them (a hoarder, with all the ids it may register) cannot take a small job whole;
    /// the others render the rest and then take spares of what it holds. An identity
    /// with [`MAX_STRIKES`] strikes (units finished by others while it held them, and
    /// leases that lapsed, less one for each result it returned) holds at most
    /// [`MIN_SHARE`]: a hoarder little, an honest one that fell behind enough to catch up.
    pub(super) fn room_in_share(&self, by: By, now: Instant) -> usize {
        let identities = self.live_identities(now).len();
        if identities < 2 {
            return usize::MAX;
        }
        let running = self.jobs.iter().filter(|e| e.job.phase == JobPhase::Running);
        let open: usize = running.clone().map(|e| e.job.queued() + e.job.units_out()).sum();
        let struck = self.identities.get(by.identity).is_some_and(|i| i.strikes >= MAX_STRIKES);
        let share = if struck { MIN_SHARE } else { open.div_ceil(identities).max(MIN_SHARE) };
        let mine = |w: WorkerId| self.workers.get(&w).is_some_and(|w| w.trust == by.identity);
        let held = running.flat_map(|e| e.job.lease_holders()).filter(|&w| mine(w)).count();
        share.saturating_sub(held)
    }

    /// The done units of `job` that an identity returned and no other confirmed, by the
    /// identity's name: what its checkpoint keeps, so that a ban after a restart still
    /// throws them away.
    pub fn unconfirmed_names(&self, job: &super::job::Job) -> Vec<(String, Vec<UnitId>)> {
        let name = |id| self.identities.get(id).map(|i| i.name.clone());
        job.unconfirmed().into_iter().filter_map(|(id, units)| Some((name(id)?, units))).collect()
    }

    /// A result of `by` for `unit` of `job` was refused as malformed: after
    /// [`MAX_REFUSED`] of them its identity is banned, as a liar is.
    pub(super) fn refused(&mut self, by: By, job: &str, unit: UnitId) {
        let Some(i) = self.identities.get_mut(by.identity) else { return };
        i.refused += 1;
        if i.refused >= MAX_REFUSED {
            let reason = format!("returned {} malformed results", i.refused);
            self.ban_for(by.identity, reason, job, unit);
        }
    }

    /// Identity `liar`'s answer for `unit` of `job` differed from the truth (two other
    /// identities that agreed, or the coordinator's own render).
    pub fn ban(&mut self, liar: IdentityId, job: &str, unit: UnitId) {
        self.ban_for(liar, format!("returned a wrong result for unit {unit} of {job}"), job, unit);
    }

    /// Bans `liar`: none of its workers gets more work or may register again, and every
    /// job throws away what it returned that no other identity confirmed.
    fn ban_for(&mut self, liar: IdentityId, reason: String, job: &str, unit: UnitId) {
        if !self.identities.ban(liar, reason.clone()) {
            return;
        }
        let name = self.identities.get(liar).map_or_else(String::new, |i| i.name.clone());
        let workers: Vec<WorkerId> = self.workers.values().filter(|w| w.trust == liar).map(|w| w.id).collect();
        tracing::warn!(identity = %name, ?workers, %job, unit, "identity banned: {reason}");
        for e in &mut self.jobs {
            let n = e.job.discard_from(liar, &workers);
            if (n > 0 || e.job.id == job) && e.job.warnings.len() < MAX_EVENTS {
                e.job.warnings.push(format!(
                    "identity {name} {reason} and was banned ({} of its workers quarantined); {n} of its units \
                     here were thrown away and render again",
                    workers.len()
                ));
            }
        }
    }
}

#[cfg(test)]
mod tests;
