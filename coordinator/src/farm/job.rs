//! A job: one image of one scene, split into units (tile × sample batch), and the state of
//! each unit. Plain Rust, no network: the services call into this, and it is tested
//! directly.

use std::collections::{BTreeSet, VecDeque};
use std::time::{Duration, Instant};

use std::sync::Arc;

use tracer::film::{Accumulation, Image, Mosaic, SampleRange, Tile};

use crate::farm::leases::LeaseClock;
use crate::farm::schedule;
/// Most units a job may have.
pub const MAX_UNITS: u64 = 1 << 22;
/// Bytes of a pixel's accumulation: three i128 sums and a u32 count.
pub const ACCUMULATION_BYTES_PER_PIXEL: u64 = 52;
/// Bytes a unit's record takes in a running job (the unit, its holders, its place in the
/// queues and the lease clock), rounded up: what a job of many tiny units costs beyond
/// its pixels.
pub const UNIT_BYTES: u64 = 384;
/// Bytes a pixel's AOV layers add, when a job keeps them.
pub const LAYER_BYTES_PER_PIXEL: u64 = tracer::film::LAYER_BYTES as u64;

pub use crate::farm::unit::{
    Applied, By, IdentityId, Rejection, Spare, Unit, UnitId, UnitRecord, UnitResult, UnitState, WorkerId,
};

#[derive(Clone, Debug, PartialEq, Eq)]
pub enum JobPhase {
    /// A frame of a job group waiting for earlier frames to finish (see
    /// `Farm::due_frames`); nothing of it is loaded yet.
    Queued,
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

/// Everything [`Job::restore`] needs.
#[derive(Clone, Debug, PartialEq)]
pub struct Restored {
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub tile_size: u32,
    pub batch_spp: u32,
    pub non_negative: bool,
    pub units: Vec<UnitRecord>,
    pub tiles: Vec<Arc<Accumulation>>,
    pub rays: u64,
    pub nonfinite: u64,
    /// The job had been cancelled: it comes back cancelled, its image so far kept.
    pub cancelled: bool,
    /// Done units that an identity (by name) returned and no other confirmed: thrown
    /// away if it is (or has been) banned.
    pub unconfirmed: Vec<(String, Vec<UnitId>)>,
}

pub struct Job {
    pub id: String,
    pub name: String,
    /// The user who submitted the job (None: an admin, or a farm without users); only
    /// they and admins may watch, fetch or cancel it.
    pub owner: Option<String>,
    /// The job group it is a frame of (its spec's).
    pub group: Option<String>,
    pub phase: JobPhase,
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub tile_size: u32,
    pub batch_spp: u32,
    /// Whether radiance must be non-negative (the path integrators; AOVs like normals
    /// are signed).
    pub non_negative: bool,
    /// Whether the job keeps the AOV layers (`[render] aovs`): set before [`Job::start`],
    /// and from its tiles on [`Job::restore`]; every result must carry them then.
    pub layers: bool,
    /// The noise target of adaptive sampling (see `job/adaptive.rs`); set before
    /// [`Job::start`] or [`Job::restore`].
    pub adaptive: Option<f32>,
    /// `--time-budget`: no unit is leased once this long has passed since the job
    /// (re)started; the job ends when the units out are in.
    pub budget: Option<Duration>,
    /// `--spp-map`: each tile's samples per pixel (empty: `spp` for every tile); set
    /// before [`Job::start`], which cuts the units to it.
    pub tile_spp: Vec<u32>,
    pub units: Vec<Unit>,
    pending: BTreeSet<UnitId>,
    /// Adaptive jobs: units waiting for their tile's previous unit to merge.
    gated: BTreeSet<UnitId>,
    /// Adaptive jobs: units of converged tiles, never rendered (and their samples).
    skipped: BTreeSet<UnitId>,
    skipped_samples: u64,
    /// Adaptive jobs: each tile's units in sample order.
    tile_units: Vec<Vec<UnitId>>,
    /// Adaptive jobs: per tile, where in `tile_units` its first unit not done may be
    /// (none before it is), so that a merge need not look at the tile's done units.
    tile_open: Vec<usize>,
    /// Each tile shared, so that the image can be written or checkpointed outside the
    /// farm's lock without a copy: a merge copies only the one tile it changes, and only
    /// while a writer still reads it.
    tiles: Vec<Arc<Accumulation>>,
    pub units_done: u64,
    pub samples_done: u64,
    pub rays: u64,
    pub nonfinite: u64,
    /// When the job was created, before its scene loaded.
    pub submitted: Instant,
    /// The same moment on the wall clock, for people.
    pub submitted_at: std::time::SystemTime,
    pub started: Instant,
    pub finished: Option<Instant>,
    /// When the first unit of this run began rendering on its worker (its result's
    /// arrival less its render time): before it, the job was loading.
    rendering_since: Option<Instant>,
    /// Samples already merged when the job (re)started.
    samples_at_start: u64,
    /// The scene's problems, found when it loaded (see [`bounded_warnings`]).
    pub warnings: Vec<String>,
    /// The unit count of a finished job whose units and sums were dropped ([`Job::evict`]).
    evicted_units: Option<u64>,
    /// How long the last units took from lease to result, newest last (at most
    /// [`UNIT_TIMES_KEPT`]): what tells a straggler from an ordinary unit.
    unit_times: VecDeque<Duration>,
    /// The leases' deadlines and ages, in order.
    clock: LeaseClock<UnitId>,
    /// Units under check that wait for another worker's answer (not leased, and not in
    /// `pending`): any worker that has not answered yet may take one.
    checking: BTreeSet<UnitId>,
    /// Identities a check caught answering wrongly, for the farm to ban.
    caught: Vec<IdentityId>,
    /// Workers whose leases lapsed, for the farm to count against their identities.
    lapsed: Vec<WorkerId>,
    /// Units merged once two identities agreed on them.
    pub units_checked: u64,
    /// Units thrown away (with the rest of their tiles) because their worker was caught
    /// lying; they render again.
    pub units_discarded: u64,
    /// Its share of the workers against other running jobs (see `schedule`).
    pub share: super::schedule::Share,
    /// Results merged, ever (a tile thrown away and rendered again counts again).
    pub merged: u64,
    /// When the last result was merged, on the wall clock (the dashboard's latency).
    pub last_merged_at: Option<std::time::SystemTime>,
    /// Checks whose answers disagreed.
    pub units_mismatched: u64,
}

/// A job's image as its tiles' accumulations, shared with the job ([`Job::image_tiles`]).
pub struct ImageTiles {
    width: u32,
    height: u32,
    tile_size: u32,
    tiles: Vec<Arc<Accumulation>>,
}

impl ImageTiles {
    /// The pixels, read in place.
    pub fn mosaic(&self) -> Mosaic<'_, Arc<Accumulation>> {
        Mosaic::new(self.width, self.height, self.tile_size, &self.tiles).expect("a job's tiles are its grid's")
    }
}

/// A tile's progress ([`Job::tile_progress`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TileProgress {
    pub tile: Tile,
    /// Samples merged over samples wanted, 0 to 1 (1 once converged).
    pub done: f32,
    /// Adaptive sampling skipped the tile's remaining units.
    pub converged: bool,
}

/// Unit times a job keeps for its median.
const UNIT_TIMES_KEPT: usize = 64;

/// A scene's warnings as a job keeps them: at most 20, each at most 500 characters, so
/// that a model with thousands of problems cannot swell every status message.
pub fn bounded_warnings(all: &[String]) -> Vec<String> {
    const MAX: usize = 20;
    let clip = |w: &String| {
        if w.chars().count() > 500 { format!("{}…", w.chars().take(500).collect::<String>()) } else { w.clone() }
    };
    let mut out: Vec<String> = all.iter().take(MAX).map(clip).collect();
    if all.len() > MAX {
        out.push(format!("… and {} more warnings", all.len() - MAX));
    }
    out
}

impl Job {
    /// A job whose scene is still loading.
    pub fn loading(id: String, name: String) -> Self {
        Self {
            id,
            name,
            owner: None,
            group: None,
            phase: JobPhase::Loading,
            width: 0,
            height: 0,
            spp: 0,
            tile_size: 0,
            batch_spp: 0,
            non_negative: true,
            layers: false,
            adaptive: None,
            budget: None,
            tile_spp: Vec::new(),
            units: Vec::new(),
            pending: BTreeSet::new(),
            gated: BTreeSet::new(),
            skipped: BTreeSet::new(),
            skipped_samples: 0,
            tile_units: Vec::new(),
            tile_open: Vec::new(),
            tiles: Vec::new(),
            units_done: 0,
            samples_done: 0,
            rays: 0,
            nonfinite: 0,
            submitted: Instant::now(),
            submitted_at: std::time::SystemTime::now(),
            started: Instant::now(),
            finished: None,
            rendering_since: None,
            samples_at_start: 0,
            warnings: Vec::new(),
            evicted_units: None,
            unit_times: VecDeque::new(),
            clock: LeaseClock::default(),
            checking: BTreeSet::new(),
            lapsed: Vec::new(),
            caught: Vec::new(),
            units_checked: 0,
            units_discarded: 0,
            share: super::schedule::Share::default(),
            merged: 0,
            last_merged_at: None,
            units_mismatched: 0,
        }
    }

    /// The scene loaded: lay out the units and start.
    pub fn start(&mut self, width: u32, height: u32, spp: u32, tile_size: u32, batch_spp: u32, non_negative: bool) {
        let tiles = Tile::grid(width, height, tile_size);
        // With an spp map, each tile's units stop at its own spp.
        let cap = |t: usize| self.tile_spp.get(t).copied().unwrap_or(spp);
        self.units = schedule::progressive_units(&tiles, spp, batch_spp)
            .into_iter()
            .filter(|&(t, samples)| samples.start < cap(t))
            .map(|(t, samples)| {
                let samples = SampleRange::new(samples.start, samples.end.min(cap(t)));
                Unit::new(t, tiles[t], samples, UnitState::Pending)
            })
            .collect();
        self.pending = (0..self.units.len() as UnitId).collect();
        self.clock.clear();
        self.tiles = tiles.into_iter().map(|t| Arc::new(Accumulation::with_layers(t, self.layers))).collect();
        (self.width, self.height, self.spp, self.non_negative) = (width, height, spp, non_negative);
        (self.tile_size, self.batch_spp) = (tile_size, batch_spp);
        self.phase = JobPhase::Running;
        (self.started, self.rendering_since) = (Instant::now(), None);
        self.reset_adaptive();
        if self.all_settled() {
            self.finish();
        }
    }

    /// Forgets adaptive sampling's placement of the units and decides it afresh.
    fn reset_adaptive(&mut self) {
        (self.gated, self.skipped, self.skipped_samples) = (BTreeSet::new(), BTreeSet::new(), 0);
        self.settle_all();
    }

    /// Continues a job from a checkpoint: its units (with what is done) and its tile
    /// accumulations. Everything is cross-checked, so an inconsistent checkpoint is
    /// refused rather than producing a wrong image.
    pub fn restore(&mut self, r: Restored) -> Result<(), String> {
        let tiles = Tile::grid(r.width, r.height, r.tile_size);
        if r.tiles.len() != tiles.len() || r.tiles.iter().zip(&tiles).any(|(a, t)| a.tile != *t) {
            return Err("its tiles do not match the image size and tile size".into());
        }
        let mut per_tile = vec![0u64; tiles.len()];
        let mut units = Vec::with_capacity(r.units.len());
        for u in &r.units {
            let t = u.tile_index as usize;
            if t >= tiles.len() || u.samples.end > r.spp || u.samples.is_empty() {
                return Err(format!("a unit ({t}, {}..{}) lies outside the job", u.samples.start, u.samples.end));
            }
            if u.done {
                per_tile[t] += u.samples.len() as u64;
            }
            let state = if u.done { UnitState::Done } else { UnitState::Pending };
            units.push(Unit::new(t, tiles[t], u.samples, state));
        }
        let layers = r.tiles.first().is_some_and(|a| a.has_layers());
        for (t, acc) in r.tiles.iter().enumerate() {
            if acc.counts.len() != acc.tile.pixel_count() || acc.sums.len() != acc.tile.pixel_count() {
                return Err(format!("tile {t} has the wrong number of pixels"));
            }
            if acc.has_layers() != layers || (layers && acc.layers.len() != acc.tile.pixel_count()) {
                return Err(format!("tile {t}'s AOV layers disagree with the other tiles'"));
            }
            if acc.counts.iter().any(|&c| c as u64 != per_tile[t]) {
                return Err(format!("tile {t}'s sample counts disagree with its finished units"));
            }
        }
        self.pending =
            units.iter().enumerate().filter(|(_, u)| u.state == UnitState::Pending).map(|(i, _)| i as UnitId).collect();
        self.clock.clear();
        self.units_done = units.iter().filter(|u| u.state == UnitState::Done).count() as u64;
        self.samples_done = units
            .iter()
            .filter(|u| u.state == UnitState::Done)
            .map(|u| u.tile.pixel_count() as u64 * u.samples.len() as u64)
            .sum();
        self.units = units;
        self.tiles = r.tiles;
        self.layers = layers;
        (self.width, self.height, self.spp, self.tile_size, self.batch_spp) =
            (r.width, r.height, r.spp, r.tile_size, r.batch_spp);
        (self.non_negative, self.rays, self.nonfinite) = (r.non_negative, r.rays, r.nonfinite);
        self.phase = JobPhase::Running;
        (self.started, self.rendering_since) = (Instant::now(), None);
        self.samples_at_start = self.samples_done;
        self.finished = None;
        self.reset_adaptive();
        if self.all_settled() {
            self.finish();
        }
        if r.cancelled {
            self.cancel();
        }
        Ok(())
    }

    /// Raises the job's samples per pixel: appends units for the new samples only, in
    /// progressive order. The samples already rendered are kept, and since merging is
    /// exact the result equals a fresh render at the new count.
    pub fn extend_spp(&mut self, spp: u32) {
        if spp <= self.spp || !matches!(self.phase, JobPhase::Running | JobPhase::Done) || self.is_evicted() {
            return;
        }
        let tiles: Vec<Tile> = self.tiles.iter().map(|a| a.tile).collect();
        let base = self.units.len() as UnitId;
        let mut start = self.spp;
        let batch = self.batch_spp.max(1);
        let mut added = 0;
        while start < spp {
            // Realign to the batch grid so that extensions look like a fresh job's units.
            let end = ((start / batch + 1) * batch).min(spp);
            for (t, tile) in tiles.iter().enumerate() {
                self.units.push(Unit::new(t, *tile, SampleRange::new(start, end), UnitState::Pending));
                self.pending.insert(base + added);
                added += 1;
            }
            start = end;
        }
        self.spp = spp;
        self.phase = JobPhase::Running;
        self.finished = None;
        self.reset_adaptive();
        if self.all_settled() {
            self.finish();
        }
    }

    /// The units as a checkpoint records them.
    pub fn records(&self) -> Vec<UnitRecord> {
        self.units
            .iter()
            .map(|u| UnitRecord {
                tile_index: u.tile_index as u32,
                samples: u.samples,
                done: u.state == UnitState::Done,
            })
            .collect()
    }

    /// The tiles, shared (a checkpoint holds them while it writes, without a copy).
    pub fn tile_accumulations(&self) -> &[Arc<Accumulation>] {
        &self.tiles
    }

    pub fn fail(&mut self, error: String) {
        if !self.phase.is_final() {
            self.phase = JobPhase::Failed(error);
            self.finished = Some(Instant::now());
            self.release_leases();
        }
    }

    pub fn cancel(&mut self) {
        if !self.phase.is_final() {
            self.phase = JobPhase::Cancelled;
            self.finished = Some(Instant::now());
            self.release_leases();
        }
    }

    /// How many units the job has (also once evicted).
    /// Units skipped by adaptive sampling do not count.
    pub fn units_total(&self) -> u64 {
        self.evicted_units.unwrap_or((self.units.len() - self.skipped.len()) as u64)
    }

    /// Drops a finished job's units and per-pixel sums (about 52 B a pixel) once its
    /// image is stored elsewhere; what `status` shows stays. Only a done job can be
    /// evicted: nothing about it can change any more.
    pub fn evict(&mut self) {
        if self.phase == JobPhase::Done && self.evicted_units.is_none() {
            self.evicted_units = Some(self.units_total());
            self.units = Vec::new();
            self.tiles = Vec::new();
            self.pending = BTreeSet::new();
            (self.gated, self.skipped, self.tile_units) = (BTreeSet::new(), BTreeSet::new(), Vec::new());
            self.clock.clear();
        }
    }

    pub fn is_evicted(&self) -> bool {
        self.evicted_units.is_some()
    }

    /// Samples skipped by adaptive sampling do not count.
    pub fn samples_total(&self) -> u64 {
        self.width as u64 * self.height as u64 * self.spp as u64 - self.skipped_samples
    }

    /// [`Job::apply_at`] now, unchecked (the tests' shorthand).
    #[cfg(test)]
    pub fn apply(&mut self, by: impl Into<By>, r: &UnitResult) -> Result<Applied, Rejection> {
        self.apply_at(by, r, Instant::now(), false)
    }

    /// Checks a result received at `now` and, if valid and new, merges it; with `check`
    /// (or when the unit is already under check) it is held until another identity's
    /// answer agrees. Merging is exact integer addition, so the final image does not
    /// depend on the order results arrive in.
    pub fn apply_at(
        &mut self,
        by: impl Into<By>,
        r: &UnitResult,
        now: Instant,
        check: bool,
    ) -> Result<Applied, Rejection> {
        let by = by.into();
        let worker = by.worker;
        match &self.phase {
            JobPhase::Running => {}
            JobPhase::Done => {
                return if r.unit < self.units_total() {
                    Ok(Applied::Duplicate)
                } else {
                    Err(Rejection::UnknownUnit(r.unit))
                };
            }
            JobPhase::Queued | JobPhase::Loading => return Err(Rejection::NotRunning("still loading")),
            JobPhase::Failed(_) | JobPhase::Cancelled => {
                return if r.unit < self.units_total() {
                    Ok(Applied::Discarded)
                } else {
                    Err(Rejection::UnknownUnit(r.unit))
                };
            }
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
        let layers_expected = if self.layers { n } else { 0 };
        if r.layers.len() != layers_expected {
            return Err(malformed(format!(
                "{} pixels of AOV layers, expected {layers_expected} (the job {} them)",
                r.layers.len(),
                if self.layers { "keeps" } else { "does not keep" }
            )));
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
        if check || unit.check.is_some() {
            return self.answer(by, r, now);
        }
        self.merge(r, now, Some(by.identity))?;
        Ok(Applied::Merged)
    }

    /// Merges a checked (`from` None) or unchecked result into its tile; the unit is done.
    fn merge(&mut self, r: &UnitResult, now: Instant, from: Option<IdentityId>) -> Result<(), Rejection> {
        let unit = &self.units[r.unit as usize];
        let (n, expected) = (unit.tile.pixel_count(), unit.samples.len());
        let malformed = |what: String| Rejection::Malformed { unit: r.unit, what };
        let tile_index = unit.tile_index;
        if let UnitState::Leased { since, .. } = unit.state {
            self.clock.ended(r.unit, since);
            // The time of an ordinary unit: a straggler's (one given a spare) measures
            // how long its first worker sat on it, and would raise the median that
            // decides what a straggler is, until none are spared in time.
            if unit.spare.is_none() {
                if self.unit_times.len() == UNIT_TIMES_KEPT {
                    self.unit_times.pop_front();
                }
                self.unit_times.push_back(now.saturating_duration_since(since));
            }
        }
        let acc = Accumulation {
            tile: unit.tile,
            sums: r.sums.clone(),
            counts: r.counts.clone(),
            nonfinite: r.nonfinite,
            layers: r.layers.clone(),
        };
        Arc::make_mut(&mut self.tiles[tile_index]).merge(&acc).map_err(|e| malformed(e.to_string()))?;
        let unit = &mut self.units[r.unit as usize];
        unit.state = UnitState::Done;
        unit.spare = None;
        unit.unchecked_from = from;
        self.pending.remove(&r.unit);
        self.units_done += 1;
        self.merged += 1;
        self.last_merged_at = Some(std::time::SystemTime::now());
        self.samples_done += n as u64 * expected as u64;
        self.rays += r.rays;
        self.nonfinite += r.nonfinite;
        self.rendered(now, r.render_seconds);
        self.settle_merged(tile_index);
        if self.all_settled() {
            self.finish();
        }
        self.budget_spent(now);
        Ok(())
    }

    /// Whether the time budget has run out; ends the job once no unit is out (so every
    /// tile stops on a whole batch, at most one batch from the others: units are leased
    /// batch by batch across the tiles).
    pub fn budget_spent(&mut self, now: Instant) -> bool {
        let Some(budget) = self.budget else { return false };
        if now.saturating_duration_since(self.started) < budget {
            return false;
        }
        let nothing_out = self.clock.oldest_out().next().is_none() && self.checking.is_empty();
        if self.phase == JobPhase::Running && nothing_out {
            self.finish();
        }
        true
    }

    fn finish(&mut self) {
        self.phase = JobPhase::Done;
        self.finished = Some(Instant::now());
    }

    /// The image as it is now, sharing the job's accumulations (no copy), to be written
    /// without holding the farm.
    pub fn image_tiles(&self) -> ImageTiles {
        ImageTiles { width: self.width, height: self.height, tile_size: self.tile_size, tiles: self.tiles.clone() }
    }

    /// The image so far (the mean of the samples merged; all of them once done).
    pub fn image(&self) -> Image {
        let mut img = Image::new(self.width, self.height);
        for acc in self.tiles.iter() {
            img.put(acc);
        }
        img
    }

    /// Units currently leased to `worker`.
    /// Each tile with the fraction of its samples merged (0 to 1; 1 once adaptive
    /// sampling judged it converged): a unit covers its whole tile, so the tile's first
    /// pixel's count is every pixel's.
    pub fn tile_progress(&self) -> Vec<TileProgress> {
        let spp = f64::from(self.spp.max(1));
        let done = |a: &Accumulation| f64::from(a.counts.first().copied().unwrap_or(0));
        let tiles = self.tiles.iter().enumerate();
        tiles
            .map(|(t, a)| {
                let converged = self.tile_converged(t);
                let done = if converged { 1.0 } else { (done(a) / spp).min(1.0) as f32 };
                TileProgress { tile: a.tile, done, converged }
            })
            .collect()
    }
}

mod adaptive;
pub use adaptive::DEFAULT_NOISE;
mod checks;
mod leasing;
mod size;
#[cfg(test)]
mod tests;
mod timing;
