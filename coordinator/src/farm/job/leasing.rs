//! Who holds a job's units: leasing the next one (or a spare against a straggler),
//! renewing a lease, returning lapsed ones to the queue, and releasing all of them when
//! the job ends.

use std::time::{Duration, Instant};

use super::{By, Job, JobPhase, Spare, UnitId, UnitState, WorkerId};
use crate::farm::leases::Slot;

/// A unit out for this many times the job's median unit time is a straggler...
const STRAGGLER_FACTOR: u32 = 3;
/// ...but never one out for less than this (tiny units would all look like stragglers).
const STRAGGLER_FLOOR: Duration = Duration::from_millis(100);

impl Job {
    /// Leases the next pending unit (progressive order) to `worker` until `deadline`.
    /// When none is pending, and a unit has been out with another worker for longer
    /// than [`Job::straggler_after`] (`speculate_after` until the job has timed a few
    /// units), the oldest such unit is leased again as a spare (speculative execution
    /// against stragglers): the first result wins.
    pub fn lease_next(
        &mut self,
        by: impl Into<By>,
        now: Instant,
        deadline: Instant,
        speculate_after: Duration,
    ) -> Option<UnitId> {
        let by = by.into();
        self.lease_next_among(by, &[by.worker], now, deadline, speculate_after)
    }

    /// [`Job::lease_next`] for a worker whose identity has the workers `siblings` (itself
    /// among them): a spare lease goes only to another identity than the unit's holders,
    /// so that an identity that holds units without returning them (a hoarder, with as
    /// many ids as it may register) cannot also take their spares.
    pub fn lease_next_among(
        &mut self,
        by: By,
        siblings: &[WorkerId],
        now: Instant,
        deadline: Instant,
        speculate_after: Duration,
    ) -> Option<UnitId> {
        if self.phase != JobPhase::Running || self.share.paused || self.budget_spent(now) {
            return None;
        }
        let By { worker, identity } = by;
        // Units under check first: the job cannot end before they are settled.
        if let Some(id) = self.next_to_check(identity).or_else(|| self.next_pending()) {
            let unit = &mut self.units[id as usize];
            unit.state = UnitState::Leased { worker, deadline, since: now };
            unit.spare = None;
            self.clock.leased(id, now, deadline);
            if !unit.holders.contains(&worker) {
                unit.holders.push(worker);
            }
            return Some(id);
        }
        let speculate_after = self.straggler_after(speculate_after);
        // Oldest leases first: the first that is old enough, has no spare and was never
        // this worker's is the one; younger ones need not be looked at.
        let units = &self.units;
        let id = self
            .clock
            .oldest_out()
            .take_while(|(since, _)| now.saturating_duration_since(*since) >= speculate_after)
            .map(|(_, id)| id)
            .find(|&id| {
                let u = &units[id as usize];
                u.spare.is_none()
                    && !u.holders.iter().any(|h| siblings.contains(h))
                    && matches!(u.state, UnitState::Leased { .. })
            })?;
        let unit = &mut self.units[id as usize];
        unit.spare = Some(Spare { worker, deadline });
        unit.holders.push(worker);
        self.clock.deadline(id, Slot::Spare, deadline);
        Some(id)
    }

    /// Extends the lease of `unit` if `worker` holds it. Returns false when the worker
    /// should abandon the unit (done, or the job is no longer running).
    pub fn renew(&mut self, worker: WorkerId, unit: UnitId, deadline: Instant) -> bool {
        if self.phase != JobPhase::Running {
            return false;
        }
        let Some(u) = self.units.get_mut(unit as usize) else { return false };
        if let Some(spare) = u.spare.as_mut()
            && spare.worker == worker
        {
            spare.deadline = deadline;
            self.clock.deadline(unit, Slot::Spare, deadline);
            return true;
        }
        match &mut u.state {
            UnitState::Leased { worker: w, deadline: d, .. } if *w == worker => {
                *d = deadline;
                self.clock.deadline(unit, Slot::Primary, deadline);
                true
            }
            // Lapsed and re-queued or leased elsewhere: the worker may still finish it
            // (its result is accepted until the unit is done).
            UnitState::Pending | UnitState::Leased { .. } => u.holders.contains(&worker),
            UnitState::Done => false,
        }
    }

    /// Returns lapsed leases to the queue (a lapsed primary lease hands over to a live
    /// spare). Returns how many units went back to the queue.
    pub fn reap_expired(&mut self, now: Instant) -> usize {
        let mut n = 0;
        while let Some((due, id, slot)) = self.clock.pop_due(now) {
            let unit = &mut self.units[id as usize];
            match slot {
                // Only the spare lease this deadline was for (not a renewed one).
                Slot::Spare => {
                    if unit.spare.is_some_and(|s| s.deadline == due) {
                        unit.spare = None;
                    }
                }
                Slot::Primary => {
                    let UnitState::Leased { worker, deadline, since } = unit.state else { continue };
                    if deadline != due {
                        continue; // renewed since
                    }
                    self.lapsed.push(worker);
                    let spare = unit.spare.take().filter(|s| s.deadline > now);
                    n += usize::from(self.hand_over(id, since, spare, now));
                }
            }
        }
        n
    }

    /// Takes `unit` back from `worker` at once (its result was refused as malformed): a
    /// spare lease on it carries on as the unit's lease, else it goes back to its queue,
    /// rather than waiting for the lease to lapse.
    pub fn release(&mut self, worker: WorkerId, unit: UnitId, now: Instant) {
        let Some(u) = self.units.get_mut(unit as usize) else { return };
        if u.spare.is_some_and(|s| s.worker == worker) {
            u.spare = None;
        }
        let UnitState::Leased { worker: w, since, .. } = u.state else { return };
        if w != worker {
            return;
        }
        let spare = u.spare.take();
        self.hand_over(unit, since, spare, now);
    }

    /// Ends the primary lease of `unit` (made at `since`): `spare`, if any, carries on as
    /// its lease; else the unit goes back to its queue (the check queue for one under
    /// check). Returns whether it went back.
    fn hand_over(&mut self, unit: UnitId, since: Instant, spare: Option<Spare>, now: Instant) -> bool {
        self.clock.ended(unit, since);
        let u = &mut self.units[unit as usize];
        match spare {
            Some(s) => {
                self.clock.leased(unit, now, s.deadline);
                u.state = UnitState::Leased { worker: s.worker, deadline: s.deadline, since: now };
                false
            }
            None => {
                if u.check.is_some() {
                    self.checking.insert(unit);
                } else {
                    self.pending.insert(unit);
                }
                u.state = UnitState::Pending;
                true
            }
        }
    }

    /// Workers whose primary leases lapsed since the last call, one entry a lease.
    pub fn take_lapsed(&mut self) -> Vec<WorkerId> {
        std::mem::take(&mut self.lapsed)
    }

    /// An ended job holds no leases: its workers are told to abandon its units at their
    /// next heartbeat, nothing lapses later, and no worker counts them as held.
    pub(super) fn release_leases(&mut self) {
        self.clock.clear();
        for (id, u) in self.units.iter_mut().enumerate() {
            u.spare = None;
            if matches!(u.state, UnitState::Leased { .. }) {
                u.state = UnitState::Pending;
                self.pending.insert(id as UnitId);
            }
        }
    }

    /// Units waiting for a worker: pending, or under check and waiting for a second answer.
    pub fn queued(&self) -> usize {
        self.pending.len() + self.checking.len()
    }

    /// Units out on a primary lease.
    pub fn units_out(&self) -> usize {
        self.clock.out()
    }

    /// The workers holding this job's units on primary leases, one entry a unit.
    pub fn lease_holders(&self) -> impl Iterator<Item = WorkerId> + '_ {
        self.clock.oldest_out().filter_map(|(_, id)| match self.units[id as usize].state {
            UnitState::Leased { worker, .. } => Some(worker),
            _ => None,
        })
    }

    /// Units `worker` holds a lease on (primary or spare). Only units out are looked at
    /// (the lease clock lists them; a spare only ever rides on a unit out), not every
    /// unit of the job: the dashboard and the metrics ask often.
    pub fn held_by(&self, worker: WorkerId) -> usize {
        self.clock
            .oldest_out()
            .filter(|&(_, id)| {
                let u = &self.units[id as usize];
                matches!(u.state, UnitState::Leased { worker: w, .. } if w == worker)
                    || u.spare.is_some_and(|s| s.worker == worker)
            })
            .count()
    }

    /// After how long a leased unit counts as a straggler, to be leased again to an idle
    /// worker: [`STRAGGLER_FACTOR`] times the median of the job's recent unit times (at
    /// least [`STRAGGLER_FLOOR`]), or `fallback` until a few units have been timed. A
    /// measure, not a constant: many jobs take less in all than any fixed wait would.
    pub fn straggler_after(&self, fallback: Duration) -> Duration {
        if self.unit_times.len() < 4 {
            return fallback;
        }
        let mut times: Vec<Duration> = self.unit_times.iter().copied().collect();
        let mid = times.len() / 2;
        let (_, median, _) = times.select_nth_unstable(mid);
        (*median * STRAGGLER_FACTOR).max(STRAGGLER_FLOOR)
    }
}
