//! Which unit next. Between jobs: a weighted fair share (stride scheduling), so that
//! running jobs split the workers in proportion to their priorities and a new job starts
//! at once beside a long one. Within a job: units are numbered in progressive order —
//! every tile's first batch, then every tile's second batch, … — so that a preview
//! refines evenly over the image, and leasing takes the lowest pending number. Neither
//! changes a pixel: a unit's samples do not depend on when or where it renders.

use tracer::film::{SampleRange, Tile};

/// The priority a job gets unless its submission gives one.
pub const DEFAULT_PRIORITY: u32 = 50;
/// Priorities run from 1 to this.
pub const MAX_PRIORITY: u32 = 1000;

/// A job's claim on the workers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Share {
    /// Its weight: of two running jobs, one of priority 3 gets three units for each one
    /// of priority 1.
    pub priority: u32,
    /// Gets no new units (those out finish and merge).
    pub paused: bool,
    /// Units leased, each counted as 1 / priority, from where the farm's clock stood
    /// when the job (re)joined the running jobs.
    vtime: f64,
}

impl Default for Share {
    fn default() -> Self {
        Self { priority: DEFAULT_PRIORITY, paused: false, vtime: 0.0 }
    }
}

/// A priority from the wire or the command line: 0 is the default, the rest must lie in
/// 1..=[`MAX_PRIORITY`].
pub fn priority(p: u32) -> Result<u32, String> {
    match p {
        0 => Ok(DEFAULT_PRIORITY),
        1..=MAX_PRIORITY => Ok(p),
        _ => Err(format!("priority {p} is out of range: 1 to {MAX_PRIORITY} (higher gets more workers)")),
    }
}

/// The farm's side of the fair share: its clock, the virtual time of the last unit
/// leased. The job served next is the one with the least virtual time among those that
/// can take a unit (the earliest submitted on a tie); a job joining (new, resumed, or
/// back from having nothing to lease) starts at the clock, so it neither waits for the
/// others' past nor claims it.
#[derive(Clone, Copy, Debug, Default)]
pub struct FairShare {
    clock: f64,
}

impl FairShare {
    /// Of `(index, share)` of the jobs that may take a unit now, the one to serve.
    pub fn pick<'a>(&self, candidates: impl Iterator<Item = (usize, &'a mut Share)>) -> Option<usize> {
        let mut best: Option<(f64, usize)> = None;
        for (k, s) in candidates {
            s.vtime = s.vtime.max(self.clock);
            if best.is_none_or(|(v, _)| s.vtime < v) {
                best = Some((s.vtime, k));
            }
        }
        best.map(|(_, k)| k)
    }

    /// The job with `share` was given a unit.
    pub fn served(&mut self, share: &mut Share) {
        self.clock = share.vtime;
        share.vtime += 1.0 / f64::from(share.priority.max(1));
    }
}

/// `(tile index, sample range)` of every unit, in progressive order.
pub fn progressive_units(tiles: &[Tile], spp: u32, batch_spp: u32) -> Vec<(usize, SampleRange)> {
    let batch = batch_spp.max(1);
    let mut units = Vec::new();
    let mut start = 0;
    while start < spp {
        let range = SampleRange::new(start, start.saturating_add(batch).min(spp));
        units.extend((0..tiles.len()).map(|t| (t, range)));
        start = range.end;
    }
    units
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Serves `n` units among jobs of `priorities` (each always able to take one).
    fn serve(priorities: &[u32], n: usize) -> Vec<usize> {
        let mut shares: Vec<Share> = priorities.iter().map(|&p| Share { priority: p, ..Share::default() }).collect();
        let mut fair = FairShare::default();
        let mut got = vec![0; shares.len()];
        for _ in 0..n {
            let k = fair.pick(shares.iter_mut().enumerate()).unwrap();
            fair.served(&mut shares[k]);
            got[k] += 1;
        }
        got
    }

    #[test]
    fn jobs_share_in_proportion_to_priority() {
        assert_eq!(serve(&[3, 1], 400), [300, 100]);
        assert_eq!(serve(&[50, 50, 100], 400), [100, 100, 200]);
        // Ties go to the earlier job, so one unit each from the first.
        assert_eq!(serve(&[1, 1], 1), [1, 0]);
    }

    #[test]
    fn a_job_that_joins_late_neither_waits_nor_takes_over() {
        let mut shares = vec![Share::default()];
        let mut fair = FairShare::default();
        for _ in 0..1000 {
            let k = fair.pick(shares.iter_mut().enumerate()).unwrap();
            fair.served(&mut shares[k]);
        }
        shares.push(Share::default());
        let mut got = [0, 0];
        for _ in 0..100 {
            let k = fair.pick(shares.iter_mut().enumerate()).unwrap();
            fair.served(&mut shares[k]);
            got[k] += 1;
        }
        assert_eq!(got, [50, 50], "from its arrival on, the new job gets half");
    }

    #[test]
    fn priorities_are_bounded() {
        assert_eq!(priority(0), Ok(DEFAULT_PRIORITY));
        assert_eq!(priority(7), Ok(7));
        assert!(priority(MAX_PRIORITY + 1).unwrap_err().contains("1 to 1000"));
    }

    #[test]
    fn last_batch_is_partial() {
        let tiles = Tile::grid(4, 4, 4);
        let u = progressive_units(&tiles, 10, 4);
        let ranges: Vec<_> = u.iter().map(|(_, r)| (r.start, r.end)).collect();
        assert_eq!(ranges, [(0, 4), (4, 8), (8, 10)]);
    }
}
