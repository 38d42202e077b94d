//! Adaptive sampling, decided from merged state only.
//!
//! A job with a noise target (`--adaptive`, `--noise`) renders each tile one batch at a
//! time: a tile's next unit is leased only once its previous one has merged, so that
//! the tile's accumulation is always exactly the sum of its first k batches, whatever
//! the workers, their number, the order results arrive in, kills and resumes. After
//! each merge the tile is judged on that accumulation alone: once it has at least
//! [`MIN_SPP`] samples and its noise ([`tile_noise`]) is at most the target, its
//! remaining units are skipped. The decision is a pure function of exact integer sums,
//! so the image (and the `samples` channel, which shows where samples went) is the same
//! bits every time.
//!
//! Skipped units are not done: a checkpoint records them as pending, and a restored
//! job decides again, from the same sums, to skip them.

use super::{Job, UnitId, UnitState};
use tracer::film::Accumulation;

/// Fewest samples a tile has before it may be judged converged: with fewer, a variance
/// estimate is itself too noisy to trust (path-traced noise is heavy-tailed: a tile's
/// rare bright paths are often not among its first few dozen samples).
pub const MIN_SPP: u32 = 64;

/// The noise target of `--adaptive` without `--noise` (and what the dashboard's noise
/// view measures other jobs against): a 1 % relative error.
pub const DEFAULT_NOISE: f32 = 0.01;

/// A tile's noise: the root mean square of its pixels' relative errors
/// ([`tracer::film::PixelLayers::relative_error`]: the standard error of the pixel's
/// value relative to its value plus a little). Infinite without the squared sums that
/// give the variance (an accumulation without layers).
pub fn tile_noise(acc: &Accumulation) -> f64 {
    if !acc.has_layers() || acc.counts.is_empty() {
        return f64::INFINITY;
    }
    let mut squares = 0.0f64;
    for i in 0..acc.counts.len() {
        let Some(l) = acc.layers_at(i) else { return f64::INFINITY };
        squares += l.relative_error(acc.mean(i)).powi(2);
    }
    (squares / acc.counts.len() as f64).sqrt()
}

impl Job {
    /// Lists each tile's units in sample order (after the units change).
    pub(super) fn index_tiles(&mut self) {
        self.tile_units = vec![Vec::new(); self.tiles.len()];
        self.tile_open = vec![0; self.tiles.len()];
        for (id, u) in self.units.iter().enumerate() {
            self.tile_units[u.tile_index].push(id as UnitId);
        }
        for ids in &mut self.tile_units {
            ids.sort_by_key(|&id| self.units[id as usize].samples.start);
        }
    }

    /// Decides every tile afresh (see [`Job::settle`]).
    pub(super) fn settle_all(&mut self) {
        if self.adaptive.is_some() {
            self.index_tiles();
            (0..self.tiles.len()).for_each(|t| self.settle(t));
        }
    }

    /// Places tile `t`'s unfinished units: none while one is out (leased or under check)
    /// but the ones after it, which wait; else, if the tile has converged, all skipped;
    /// else the first pending and the rest waiting. Only for adaptive jobs.
    pub(super) fn settle(&mut self, t: usize) {
        let Some(target) = self.adaptive else { return };
        self.tile_open[t] = 0;
        let ids = std::mem::take(&mut self.tile_units[t]);
        let open: Vec<UnitId> =
            ids.iter().copied().filter(|&id| self.units[id as usize].state != UnitState::Done).collect();
        let out = |job: &Job, id: UnitId| {
            matches!(job.units[id as usize].state, UnitState::Leased { .. }) || job.checking.contains(&id)
        };
        let first_out = open.first().is_some_and(|&id| out(self, id));
        let acc = &self.tiles[t];
        let converged =
            !first_out && acc.counts.first().is_some_and(|&n| n >= MIN_SPP) && { tile_noise(acc) <= f64::from(target) };
        for (k, &id) in open.iter().enumerate() {
            if k == 0 && first_out {
                continue;
            }
            self.pending.remove(&id);
            self.gated.remove(&id);
            if self.skipped.remove(&id) {
                self.skipped_samples -= self.unit_samples(id);
            }
            if converged {
                self.skipped.insert(id);
                self.skipped_samples += self.unit_samples(id);
            } else if k == 0 {
                self.pending.insert(id);
            } else {
                self.gated.insert(id);
            }
        }
        self.tile_units[t] = ids;
    }

    /// [`Job::settle`] after a merge into tile `t`, in time independent of the tile's
    /// unit count (a long adaptive render has many): the tile's next batch becomes
    /// leasable, unless the tile has converged (then the full form skips the rest).
    pub(super) fn settle_merged(&mut self, t: usize) {
        let Some(target) = self.adaptive else { return };
        let Some(first) = self.first_open(t) else { return };
        if matches!(self.units[first as usize].state, UnitState::Leased { .. }) || self.checking.contains(&first) {
            return;
        }
        let acc = &self.tiles[t];
        let converged = acc.counts.first().is_some_and(|&n| n >= MIN_SPP) && tile_noise(acc) <= f64::from(target);
        if converged || self.skipped.contains(&first) {
            self.settle(t);
        } else if self.gated.remove(&first) {
            self.pending.insert(first);
        }
    }

    /// The pending unit to lease next: the first (the furthest behind: units are
    /// numbered batch by batch). An adaptive job on a time budget also keeps its tiles in
    /// step: no tile leases a batch more than one ahead of the open tile furthest behind,
    /// so that when the budget ends every open tile is within one batch of the others
    /// (its tiles' chains of batches run at their own pace otherwise).
    pub(super) fn next_pending(&mut self) -> Option<UnitId> {
        let &first = self.pending.first()?;
        if self.adaptive.is_some()
            && self.budget.is_some()
            && let Some(behind) = self.furthest_behind()
            && self.units[first as usize].samples.start > behind.saturating_add(self.batch_spp.max(1))
        {
            return None;
        }
        self.pending.pop_first()
    }

    /// The lowest first sample of any open tile's next unit (pending or out; tiles that
    /// converged are not open). Advances the tiles' cursors past done units.
    fn furthest_behind(&mut self) -> Option<u32> {
        let mut behind = None::<u32>;
        for t in 0..self.tile_units.len() {
            if let Some(id) = self.first_open(t)
                && !self.skipped.contains(&id)
            {
                let start = self.units[id as usize].samples.start;
                behind = Some(behind.map_or(start, |b| b.min(start)));
            }
        }
        behind
    }

    /// Tile `t`'s first unit not done, advancing its cursor past the done ones.
    fn first_open(&mut self, t: usize) -> Option<UnitId> {
        let ids = &self.tile_units[t];
        let mut k = self.tile_open[t];
        while k < ids.len() && self.units[ids[k] as usize].state == UnitState::Done {
            k += 1;
        }
        self.tile_open[t] = k;
        ids.get(k).copied()
    }

    /// Samples (pixels × samples per pixel) of unit `id`.
    fn unit_samples(&self, id: UnitId) -> u64 {
        let u = &self.units[id as usize];
        u.tile.pixel_count() as u64 * u64::from(u.samples.len())
    }

    /// Whether tile `t` has converged: adaptive sampling skipped its remaining units.
    pub fn tile_converged(&self, t: usize) -> bool {
        self.tile_units.get(t).is_some_and(|ids| ids.last().is_some_and(|id| self.skipped.contains(id)))
    }

    /// The relative error the dashboard's noise view centres on: the job's target, else
    /// [`DEFAULT_NOISE`].
    pub fn noise_target(&self) -> f64 {
        f64::from(self.adaptive.unwrap_or(DEFAULT_NOISE))
    }

    /// Whether every unit is done or skipped.
    pub(super) fn all_settled(&self) -> bool {
        self.units_done + self.skipped.len() as u64 == self.units.len() as u64
    }
}
