//! A job's side of verified results (see [`crate::farm::verify`]): holding a checked
//! unit's answers until two identities agree, leasing it to identities that have not
//! answered, and throwing away what an identity caught lying contributed.

use std::collections::BTreeSet;
use std::time::Instant;

use tracer::film::Accumulation;

use super::{Applied, By, IdentityId, Job, JobPhase, Rejection, UnitId, UnitResult, UnitState, WorkerId};
use crate::farm::verify::{MAX_ANSWERS, Outcome};

impl Job {
    /// A unit under check that `identity` has not answered, taken off the check queue.
    pub(super) fn next_to_check(&mut self, identity: IdentityId) -> Option<UnitId> {
        let units = &self.units;
        let id = self
            .checking
            .iter()
            .copied()
            .find(|&id| !units[id as usize].check.as_ref().is_some_and(|c| c.answered(identity)))?;
        self.checking.remove(&id);
        Some(id)
    }

    /// Takes the answer of `by` for a unit under check (a valid result, not done yet). An
    /// identity answers once: a second answer through another of its workers is a
    /// duplicate, and vouches for nothing.
    pub(super) fn answer(&mut self, by: By, r: &UnitResult, now: Instant) -> Result<Applied, Rejection> {
        let id = r.unit;
        let unit = &mut self.units[id as usize];
        let check = unit.check.get_or_insert_with(Default::default);
        if check.answered(by.identity) {
            return Ok(Applied::Duplicate);
        }
        match check.add(by, r) {
            Outcome::Open => {
                // Another identity must render it: off this worker's lease, onto the check
                // queue (unless another worker is already on it).
                match unit.state {
                    UnitState::Leased { worker: w, since, .. } if w == by.worker => {
                        self.clock.ended(id, since);
                        unit.state = UnitState::Pending;
                        unit.spare = None;
                        self.checking.insert(id);
                    }
                    UnitState::Leased { .. } => {
                        // It answered on a spare lease: free the spare for another
                        // identity, rather than leave it with one that has answered.
                        if unit.spare.is_some_and(|s| s.worker == by.worker) {
                            unit.spare = None;
                        }
                    }
                    _ => {
                        self.checking.insert(id);
                    }
                }
                self.pending.remove(&id);
                Ok(Applied::Held)
            }
            Outcome::Settled { agreed, liars } => {
                let check = unit.check.take().expect("the check just answered");
                self.checking.remove(&id);
                self.units_mismatched += u64::from(!liars.is_empty());
                self.caught.extend(liars);
                self.merge(&check.answers[agreed].result, now, None)?;
                self.units_checked += 1;
                Ok(Applied::Merged)
            }
            Outcome::Undecidable => {
                self.units_mismatched += 1;
                self.fail(format!(
                    "unit {id}: {MAX_ANSWERS} identities returned {MAX_ANSWERS} different results for it, so none \
                     can be trusted (several workers are broken or lying)"
                ));
                Ok(Applied::Discarded)
            }
        }
    }

    /// Units under check that no identity in `live` can settle (each has answered; or
    /// only one identity is live and has answered): taken off the check queue, for the
    /// coordinator to render itself ([`Job::arbitrate`]). A farm of two identities, one
    /// of them lying, ends this way, and so does every check on a farm of one identity.
    pub fn disputes_nobody_can_settle(&mut self, live: &[IdentityId]) -> Vec<UnitId> {
        if self.phase != JobPhase::Running {
            return Vec::new();
        }
        let units = &self.units;
        let stuck: Vec<UnitId> = self
            .checking
            .iter()
            .copied()
            .filter(|&id| {
                units[id as usize]
                    .check
                    .as_ref()
                    .is_some_and(|c| !c.answers.is_empty() && live.iter().all(|&i| c.answered(i)))
            })
            .collect();
        for id in &stuck {
            self.checking.remove(id);
        }
        stuck
    }

    /// The coordinator's own render of a disputed unit: the truth. Every answer that
    /// differs from it was a lie.
    pub fn arbitrate(&mut self, r: &UnitResult, now: Instant) -> Result<Applied, Rejection> {
        let unit = self.units.get_mut(r.unit as usize).ok_or(Rejection::UnknownUnit(r.unit))?;
        if self.phase != JobPhase::Running || unit.state == UnitState::Done {
            return Ok(Applied::Duplicate);
        }
        let truth = crate::farm::verify::digest(r);
        if let Some(check) = unit.check.take() {
            self.caught.extend(check.answers.iter().filter(|a| a.digest != truth).map(|a| a.by.identity));
        }
        self.checking.remove(&r.unit);
        self.merge(r, now, None)?;
        self.units_checked += 1;
        Ok(Applied::Merged)
    }

    /// Puts a unit the coordinator failed to render back on the check queue.
    pub fn arbitration_failed(&mut self, unit: UnitId) {
        if self.units.get(unit as usize).is_some_and(|u| u.check.is_some() && u.state != UnitState::Done) {
            self.checking.insert(unit);
        }
    }

    /// Identities caught answering wrongly since the last call.
    pub fn take_caught(&mut self) -> Vec<IdentityId> {
        std::mem::take(&mut self.caught)
    }

    /// Units waiting for a check.
    #[cfg(test)]
    pub fn units_in_check(&self) -> usize {
        self.checking.len()
    }

    /// Done units each identity returned that no other identity confirmed.
    pub fn unconfirmed(&self) -> std::collections::BTreeMap<IdentityId, Vec<UnitId>> {
        let mut by = std::collections::BTreeMap::<IdentityId, Vec<UnitId>>::new();
        for (id, u) in self.units.iter().enumerate() {
            if let (UnitState::Done, Some(who)) = (&u.state, u.unchecked_from) {
                by.entry(who).or_default().push(id as UnitId);
            }
        }
        by
    }

    /// Marks restored done `units` as returned by `identity` and not confirmed.
    pub fn mark_unconfirmed(&mut self, identity: IdentityId, units: &[UnitId]) {
        for &id in units {
            if let Some(u) = self.units.get_mut(id as usize).filter(|u| u.state == UnitState::Done) {
                u.unchecked_from = Some(identity);
            }
        }
    }

    /// Throws away everything identity `liar` (whose workers are `workers`) contributed:
    /// its answers to checks, its workers' leases, and every tile holding a result it
    /// returned that no other identity confirmed (those tiles render again, their honest
    /// units too: the merged sums cannot be taken apart). Units it settled with another
    /// identity stay: that identity vouches for them. Returns the units thrown away. A
    /// job already evicted (its image stored) cannot be reopened.
    pub fn discard_from(&mut self, liar: IdentityId, workers: &[WorkerId]) -> u64 {
        if self.is_evicted() || self.phase == JobPhase::Loading {
            return 0;
        }
        let mut tainted = BTreeSet::new();
        for (id, u) in self.units.iter_mut().enumerate() {
            let id = id as UnitId;
            if let Some(c) = u.check.as_mut() {
                c.drop_identity(liar);
            }
            if let UnitState::Leased { worker, since, .. } = u.state
                && workers.contains(&worker)
            {
                self.clock.ended(id, since);
                u.state = UnitState::Pending;
                if u.check.is_some() {
                    self.checking.insert(id)
                } else {
                    self.pending.insert(id)
                };
            }
            if u.spare.is_some_and(|s| workers.contains(&s.worker)) {
                u.spare = None;
            }
            u.holders.retain(|w| !workers.contains(w));
            if u.state == UnitState::Done && u.unchecked_from == Some(liar) {
                tainted.insert(u.tile_index);
            }
        }
        let mut discarded = 0;
        for (id, u) in self.units.iter_mut().enumerate() {
            if u.state == UnitState::Done && tainted.contains(&u.tile_index) {
                discarded += u64::from(u.unchecked_from == Some(liar));
                u.state = UnitState::Pending;
                u.unchecked_from = None;
                self.pending.insert(id as UnitId);
                self.units_done -= 1;
                self.samples_done -= u.tile.pixel_count() as u64 * u.samples.len() as u64;
            }
        }
        for &t in &tainted {
            self.nonfinite -= self.tiles[t].nonfinite.min(self.nonfinite);
            self.tiles[t] = std::sync::Arc::new(Accumulation::with_layers(self.tiles[t].tile, self.layers));
        }
        if self.adaptive.is_some() && !tainted.is_empty() {
            // A tainted tile starts again from its first batch: a later batch still out
            // would merge into the wrong prefix, so its lease is withdrawn (and its result
            // refused: it has no holder any more).
            for (id, u) in self.units.iter_mut().enumerate() {
                if let UnitState::Leased { since, .. } = u.state
                    && tainted.contains(&u.tile_index)
                {
                    self.clock.ended(id as UnitId, since);
                    (u.state, u.spare) = (UnitState::Pending, None);
                    u.holders.clear();
                }
            }
            tainted.iter().for_each(|&t| self.settle(t));
        }
        if !tainted.is_empty() && self.phase == JobPhase::Done {
            self.phase = JobPhase::Running;
            self.finished = None;
        }
        self.units_discarded += discarded;
        discarded
    }
}
