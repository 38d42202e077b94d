//! A job: one image of one scene, split into units (tile × sample batch), and the state of
//! each unit. Plain Rust, no network: the services call into this, and it is tested
//! directly.

use std::collections::BTreeSet;
use std::time::{Duration, Instant};

use tracer::film::{Accumulation, Image, SampleRange, Tile};

use crate::schedule;

pub type WorkerId = u64;
pub type UnitId = u64;

#[derive(Clone, Debug, PartialEq, Eq)]
pub enum JobPhase {
    /// The scene is being loaded and checked.
    Loading,
    Running,
    Done,
    Failed(String),
    Cancelled,
}

impl JobPhase {
    pub fn is_final(&self) -> bool {
        matches!(self, JobPhase::Done | JobPhase::Failed(_) | JobPhase::Cancelled)
    }
}

#[derive(Clone, Debug, PartialEq, Eq)]
pub enum UnitState {
    Pending,
    Leased { worker: WorkerId, deadline: Instant },
    Done,
}

#[derive(Clone, Debug)]
pub struct Unit {
    pub tile_index: usize,
    pub tile: Tile,
    pub samples: SampleRange,
    pub state: UnitState,
    /// Every worker that ever held a lease on this unit: a late result from any of them is
    /// the same deterministic work, so it is accepted while the unit is not done.
    pub holders: Vec<WorkerId>,
}

/// Why a result was refused. The job's state is untouched in every case.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum Rejection {
    #[error("unit {0} does not exist in this job")]
    UnknownUnit(UnitId),
    #[error("unit {0} was never leased to worker {1}")]
    NotHolder(UnitId, WorkerId),
    #[error("unit {unit}: {what}")]
    Malformed { unit: UnitId, what: String },
    #[error("the job is {0}")]
    NotRunning(&'static str),
}

/// What happened to a valid result.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Applied {
    Merged,
    /// The unit was already done: acknowledged and ignored.
    Duplicate,
}

/// The contents of one unit's result, as received.
#[derive(Clone, Debug)]
pub struct UnitResult {
    pub unit: UnitId,
    pub tile: Tile,
    pub samples: SampleRange,
    pub sums: Vec<[i128; 3]>,
    pub counts: Vec<u32>,
    pub nonfinite: u64,
    pub rays: u64,
}

pub struct Job {
    pub id: String,
    pub name: String,
    pub phase: JobPhase,
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    /// Whether radiance must be non-negative (the path integrators; AOVs like normals
    /// are signed).
    pub non_negative: bool,
    pub units: Vec<Unit>,
    pending: BTreeSet<UnitId>,
    tiles: Vec<Accumulation>,
    pub units_done: u64,
    pub samples_done: u64,
    pub rays: u64,
    pub nonfinite: u64,
    pub started: Instant,
    pub finished: Option<Instant>,
}

impl Job {
    /// A job whose scene is still loading.
    pub fn loading(id: String, name: String) -> Self {
        Self {
            id,
            name,
            phase: JobPhase::Loading,
            width: 0,
            height: 0,
            spp: 0,
            non_negative: true,
            units: Vec::new(),
            pending: BTreeSet::new(),
            tiles: Vec::new(),
            units_done: 0,
            samples_done: 0,
            rays: 0,
            nonfinite: 0,
            started: Instant::now(),
            finished: None,
        }
    }

    /// The scene loaded: lay out the units and start.
    pub fn start(&mut self, width: u32, height: u32, spp: u32, tile_size: u32, batch_spp: u32, non_negative: bool) {
        let tiles = Tile::grid(width, height, tile_size);
        self.units = schedule::progressive_units(&tiles, spp, batch_spp)
            .into_iter()
            .map(|(tile_index, samples)| Unit {
                tile_index,
                tile: tiles[tile_index],
                samples,
                state: UnitState::Pending,
                holders: Vec::new(),
            })
            .collect();
        self.pending = (0..self.units.len() as UnitId).collect();
        self.tiles = tiles.into_iter().map(Accumulation::new).collect();
        (self.width, self.height, self.spp, self.non_negative) = (width, height, spp, non_negative);
        self.phase = JobPhase::Running;
        self.started = Instant::now();
        if self.units.is_empty() {
            self.finish();
        }
    }

    pub fn fail(&mut self, error: String) {
        if !self.phase.is_final() {
            self.phase = JobPhase::Failed(error);
            self.finished = Some(Instant::now());
        }
    }

    pub fn cancel(&mut self) {
        if !self.phase.is_final() {
            self.phase = JobPhase::Cancelled;
            self.finished = Some(Instant::now());
        }
    }

    pub fn samples_total(&self) -> u64 {
        self.width as u64 * self.height as u64 * self.spp as u64
    }

    /// Leases the next pending unit (progressive order) to `worker` until `deadline`.
    pub fn lease_next(&mut self, worker: WorkerId, deadline: Instant) -> Option<UnitId> {
        if self.phase != JobPhase::Running {
            return None;
        }
        let id = self.pending.pop_first()?;
        let unit = &mut self.units[id as usize];
        unit.state = UnitState::Leased { worker, deadline };
        if !unit.holders.contains(&worker) {
            unit.holders.push(worker);
        }
        Some(id)
    }

    /// Extends the lease of `unit` if `worker` holds it. Returns false when the worker
    /// should abandon the unit (done, or the job is no longer running).
    pub fn renew(&mut self, worker: WorkerId, unit: UnitId, deadline: Instant) -> bool {
        if self.phase != JobPhase::Running {
            return false;
        }
        match self.units.get_mut(unit as usize) {
            Some(Unit { state: UnitState::Leased { worker: w, deadline: d }, .. }) if *w == worker => {
                *d = deadline;
                true
            }
            // Lapsed and re-queued or leased elsewhere: the worker may still finish it
            // (its result is accepted until the unit is done).
            Some(Unit { state: UnitState::Pending | UnitState::Leased { .. }, holders, .. }) => {
                holders.contains(&worker)
            }
            _ => false,
        }
    }

    /// Returns lapsed leases to the queue. Returns how many.
    pub fn reap_expired(&mut self, now: Instant) -> usize {
        let mut n = 0;
        for (id, unit) in self.units.iter_mut().enumerate() {
            if let UnitState::Leased { deadline, .. } = unit.state
                && deadline <= now
            {
                unit.state = UnitState::Pending;
                self.pending.insert(id as UnitId);
                n += 1;
            }
        }
        n
    }

    /// Checks a result and, if valid and new, merges it. Merging is exact integer
    /// addition, so the final image does not depend on the order results arrive in.
    pub fn apply(&mut self, worker: WorkerId, r: &UnitResult) -> Result<Applied, Rejection> {
        match &self.phase {
            JobPhase::Running => {}
            JobPhase::Done => {
                return if (r.unit as usize) < self.units.len() {
                    Ok(Applied::Duplicate)
                } else {
                    Err(Rejection::UnknownUnit(r.unit))
                };
            }
            JobPhase::Loading => return Err(Rejection::NotRunning("still loading")),
            JobPhase::Failed(_) => return Err(Rejection::NotRunning("failed")),
            JobPhase::Cancelled => return Err(Rejection::NotRunning("cancelled")),
        }
        let unit = self.units.get(r.unit as usize).ok_or(Rejection::UnknownUnit(r.unit))?;
        if !unit.holders.contains(&worker) {
            return Err(Rejection::NotHolder(r.unit, worker));
        }
        let malformed = |what: String| Rejection::Malformed { unit: r.unit, what };
        if r.tile != unit.tile {
            return Err(malformed(format!("tile {:?} does not match the unit's {:?}", r.tile, unit.tile)));
        }
        if r.samples != unit.samples {
            return Err(malformed(format!(
                "samples {}..{} do not match the unit's {}..{}",
                r.samples.start, r.samples.end, unit.samples.start, unit.samples.end
            )));
        }
        let n = unit.tile.pixel_count();
        if r.sums.len() != n || r.counts.len() != n {
            return Err(malformed(format!("{} sums and {} counts for {n} pixels", r.sums.len(), r.counts.len())));
        }
        let expected = unit.samples.len();
        if let Some(c) = r.counts.iter().find(|&&c| c != expected) {
            return Err(malformed(format!("a pixel has {c} samples, expected {expected}")));
        }
        if self.non_negative && r.sums.iter().flatten().any(|&v| v < 0) {
            return Err(malformed("negative radiance".into()));
        }
        if unit.state == UnitState::Done {
            return Ok(Applied::Duplicate);
        }
        let tile_index = unit.tile_index;
        let acc =
            Accumulation { tile: unit.tile, sums: r.sums.clone(), counts: r.counts.clone(), nonfinite: r.nonfinite };
        self.tiles[tile_index].merge(&acc).map_err(|e| malformed(e.to_string()))?;
        self.units[r.unit as usize].state = UnitState::Done;
        self.pending.remove(&r.unit);
        self.units_done += 1;
        self.samples_done += n as u64 * expected as u64;
        self.rays += r.rays;
        self.nonfinite += r.nonfinite;
        if self.units_done == self.units.len() as u64 {
            self.finish();
        }
        Ok(Applied::Merged)
    }

    fn finish(&mut self) {
        self.phase = JobPhase::Done;
        self.finished = Some(Instant::now());
    }

    /// The image so far (the mean of the samples merged; all of them once done).
    pub fn image(&self) -> Image {
        let mut img = Image::new(self.width, self.height);
        for acc in &self.tiles {
            img.put(acc);
        }
        img
    }

    pub fn elapsed(&self) -> Duration {
        self.finished.unwrap_or_else(Instant::now).saturating_duration_since(self.started)
    }

    /// Units currently leased to `worker`.
    pub fn held_by(&self, worker: WorkerId) -> usize {
        self.units.iter().filter(|u| matches!(u.state, UnitState::Leased { worker: w, .. } if w == worker)).count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn job() -> Job {
        let mut j = Job::loading("j1".into(), "test".into());
        j.start(5, 3, 4, 2, 2, true);
        j
    }

    fn result_for(j: &Job, unit: UnitId, value: i128) -> UnitResult {
        let u = &j.units[unit as usize];
        let n = u.tile.pixel_count();
        UnitResult {
            unit,
            tile: u.tile,
            samples: u.samples,
            sums: vec![[value; 3]; n],
            counts: vec![u.samples.len(); n],
            nonfinite: 0,
            rays: 10,
        }
    }

    #[test]
    fn units_cover_every_pixel_and_sample_once_in_progressive_order() {
        let j = job();
        // 3×2 tiles of at most 2×2, spp 4 in batches of 2: 12 units, batch 0 first.
        assert_eq!(j.units.len(), 12);
        assert!(j.units[..6].iter().all(|u| u.samples == SampleRange::new(0, 2)));
        assert!(j.units[6..].iter().all(|u| u.samples == SampleRange::new(2, 4)));
        let total: u64 = j.units.iter().map(|u| u.tile.pixel_count() as u64 * u.samples.len() as u64).sum();
        assert_eq!(total, j.samples_total());
    }

    #[test]
    fn results_merge_once_in_any_order_and_duplicates_are_ignored() {
        let now = Instant::now() + Duration::from_secs(60);
        let mut a = job();
        let mut b = job();
        let ids_a: Vec<_> = (0..12).map(|_| a.lease_next(1, now).unwrap()).collect();
        let ids_b: Vec<_> = (0..12).map(|_| b.lease_next(1, now).unwrap()).collect();
        for &id in &ids_a {
            let r = result_for(&a, id, 1000 + id as i128);
            assert_eq!(a.apply(1, &r), Ok(Applied::Merged));
        }
        for &id in ids_b.iter().rev() {
            let r = result_for(&b, id, 1000 + id as i128);
            assert_eq!(b.apply(1, &r), Ok(Applied::Merged));
            assert_eq!(b.apply(1, &r), Ok(Applied::Duplicate));
        }
        assert_eq!(a.phase, JobPhase::Done);
        assert_eq!(a.image(), b.image());
        assert_eq!(a.samples_done, a.samples_total());
        assert_eq!(b.units_done, 12);
    }

    #[test]
    fn malformed_and_foreign_results_are_rejected_without_touching_state() {
        let deadline = Instant::now() + Duration::from_secs(60);
        let mut j = job();
        let id = j.lease_next(7, deadline).unwrap();
        let good = result_for(&j, id, 5);
        let before = j.image();
        assert_eq!(j.apply(8, &good), Err(Rejection::NotHolder(id, 8)));
        let mut r = good.clone();
        r.unit = 99;
        assert_eq!(j.apply(7, &r), Err(Rejection::UnknownUnit(99)));
        let mut r = good.clone();
        r.tile.width += 1;
        assert!(matches!(j.apply(7, &r), Err(Rejection::Malformed { .. })));
        let mut r = good.clone();
        r.sums.pop();
        assert!(matches!(j.apply(7, &r), Err(Rejection::Malformed { .. })));
        let mut r = good.clone();
        r.counts[0] += 1;
        assert!(matches!(j.apply(7, &r), Err(Rejection::Malformed { .. })));
        let mut r = good.clone();
        r.sums[0][1] = -1;
        assert!(matches!(j.apply(7, &r), Err(Rejection::Malformed { .. })));
        let mut r = good.clone();
        r.samples.end += 1;
        assert!(matches!(j.apply(7, &r), Err(Rejection::Malformed { .. })));
        assert_eq!(j.image(), before);
        assert_eq!(j.units_done, 0);
        assert_eq!(j.apply(7, &good), Ok(Applied::Merged));
    }

    #[test]
    fn lapsed_leases_return_to_the_queue_and_late_results_still_count() {
        let t0 = Instant::now();
        let mut j = job();
        let id = j.lease_next(1, t0 + Duration::from_millis(10)).unwrap();
        assert_eq!(j.reap_expired(t0 + Duration::from_millis(20)), 1);
        // Re-leased to another worker; the first comes back late with the result.
        assert_eq!(j.lease_next(2, t0 + Duration::from_secs(60)), Some(id));
        let r = result_for(&j, id, 3);
        assert_eq!(j.apply(1, &r), Ok(Applied::Merged));
        assert_eq!(j.apply(2, &r), Ok(Applied::Duplicate));
        assert!(!j.renew(2, id, t0 + Duration::from_secs(90)), "done units are abandoned");
    }

    #[test]
    fn cancelled_jobs_lease_nothing_and_refuse_results() {
        let mut j = job();
        let id = j.lease_next(1, Instant::now() + Duration::from_secs(5)).unwrap();
        j.cancel();
        assert_eq!(j.lease_next(1, Instant::now()), None);
        assert_eq!(j.apply(1, &result_for(&j, id, 1)), Err(Rejection::NotRunning("cancelled")));
    }
}
