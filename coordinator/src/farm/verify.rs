//! Verified results. A unit's result is a pure function of (scene, unit), so two honest
//! workers return the same bits. A unit chosen for checking is not merged on its first
//! answer: it is rendered again by a different worker, and merged only once two answers
//! agree bit for bit. Any answer that differs from the agreed one came from a worker
//! that lied (or is broken), which the farm then quarantines.
//!
//! Which units are checked is decided with a key only the coordinator knows, so a
//! worker cannot tell a checked unit from any other.

use sha2::{Digest, Sha256};

use proto::domain::UnitResult;

use super::ids::{UnitId, WorkerId};

/// Most answers one unit collects before two agree: with honest workers it takes two;
/// more means several workers disagree with each other.
pub const MAX_ANSWERS: usize = 5;

/// One worker's answer for a unit under check.
#[derive(Clone, Debug)]
pub struct Answer {
    pub worker: WorkerId,
    pub digest: [u8; 32],
    pub result: UnitResult,
}

/// The answers a checked unit has collected so far.
#[derive(Clone, Debug, Default)]
pub struct Check {
    pub answers: Vec<Answer>,
}

/// What a new answer settled.
#[derive(Debug, PartialEq, Eq)]
pub enum Outcome {
    /// No two answers agree yet: another worker must render the unit.
    Open,
    /// Two answers agree: merge answer `agreed`; `liars` answered otherwise.
    Settled { agreed: usize, liars: Vec<WorkerId> },
    /// [`MAX_ANSWERS`] answers and no two agree: nothing can be trusted.
    Undecidable,
}

impl Check {
    pub fn answered(&self, worker: WorkerId) -> bool {
        self.answers.iter().any(|a| a.worker == worker)
    }

    /// Adds `worker`'s answer (the caller made sure it is its first) and says what it
    /// settled.
    pub fn add(&mut self, worker: WorkerId, result: &UnitResult) -> Outcome {
        self.answers.push(Answer { worker, digest: digest(result), result: result.clone() });
        self.outcome()
    }

    fn outcome(&self) -> Outcome {
        for (i, a) in self.answers.iter().enumerate() {
            if self.answers[i + 1..].iter().any(|b| b.digest == a.digest) {
                let liars = self.answers.iter().filter(|b| b.digest != a.digest).map(|b| b.worker).collect();
                return Outcome::Settled { agreed: i, liars };
            }
        }
        if self.answers.len() >= MAX_ANSWERS { Outcome::Undecidable } else { Outcome::Open }
    }

    /// Forgets a quarantined worker's answer.
    pub fn drop_worker(&mut self, worker: WorkerId) {
        self.answers.retain(|a| a.worker != worker);
    }
}

/// The bits of a result that make the image: its sums, counts, non-finite count and
/// any AOV layers.
pub fn digest(r: &UnitResult) -> [u8; 32] {
    let mut h = Sha256::new();
    h.update(r.nonfinite.to_le_bytes());
    for (s, c) in r.sums.iter().zip(&r.counts) {
        for v in s {
            h.update(v.to_le_bytes());
        }
        h.update(c.to_le_bytes());
    }
    for v in r.layers.iter().flatten() {
        h.update(v.to_le_bytes());
    }
    h.finalize().into()
}

/// Which units to check: a secret key, and the fraction of units (also every unit of a
/// worker's first few results).
#[derive(Clone)]
pub struct Policy {
    key: [u8; 32],
    /// Fraction of units checked, 0 to 1.
    pub fraction: f64,
    /// Every result of a worker's first this-many is checked (when `fraction` > 0).
    pub first_results: u64,
}

impl std::fmt::Debug for Policy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Policy {{ fraction: {}, first_results: {} }}", self.fraction, self.first_results)
    }
}

impl Default for Policy {
    /// No checks (a local render's own workers).
    fn default() -> Self {
        Self { key: [0; 32], fraction: 0.0, first_results: 0 }
    }
}

impl Policy {
    /// Checks `fraction` of units and a new worker's first `first_results`, choosing
    /// with a fresh random key.
    pub fn new(fraction: f64, first_results: u64) -> Result<Self, String> {
        if !(0.0..=1.0).contains(&fraction) {
            return Err(format!("--verify {fraction}: a fraction between 0 and 1"));
        }
        let mut key = [0u8; 32];
        getrandom::fill(&mut key).map_err(|e| format!("no randomness for choosing checked units: {e}"))?;
        Ok(Self { key, fraction, first_results })
    }

    pub fn enabled(&self) -> bool {
        self.fraction > 0.0
    }

    /// Is this result to be checked? `answers_before` counts the worker's earlier results.
    pub fn must_check(&self, answers_before: u64, job: &str, unit: UnitId) -> bool {
        if !self.enabled() {
            return false;
        }
        if answers_before < self.first_results {
            return true;
        }
        let mut h = Sha256::new();
        h.update(self.key);
        h.update(job.as_bytes());
        h.update(unit.to_le_bytes());
        let x = u64::from_le_bytes(h.finalize()[..8].try_into().expect("8 bytes"));
        (x as f64) < self.fraction * 18_446_744_073_709_551_616.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tracer::film::{SampleRange, Tile};

    fn result(v: i128) -> UnitResult {
        UnitResult {
            unit: 3,
            tile: Tile::new(0, 0, 1, 1),
            samples: SampleRange::new(0, 4),
            sums: vec![[v, v, v]],
            counts: vec![4],
            layers: Vec::new(),
            rays: 10,
            nonfinite: 0,
            render_seconds: 0.0,
        }
    }

    #[test]
    fn two_agreeing_answers_settle_and_name_the_one_that_differs() {
        let mut c = Check::default();
        assert_eq!(c.add(1, &result(7)), Outcome::Open);
        assert_eq!(c.add(2, &result(8)), Outcome::Open, "two answers that differ need a third");
        assert_eq!(c.add(3, &result(7)), Outcome::Settled { agreed: 0, liars: vec![2] });
        let mut c = Check::default();
        c.add(1, &result(9));
        assert_eq!(c.add(2, &result(7)), Outcome::Open);
        assert_eq!(c.add(3, &result(7)), Outcome::Settled { agreed: 1, liars: vec![1] });
        assert!(c.answered(1) && !c.answered(4));
        c.drop_worker(1);
        assert_eq!(c.answers.len(), 2);
    }

    #[test]
    fn one_bit_makes_a_different_answer() {
        let mut r = result(7);
        let d = digest(&r);
        r.sums[0][2] ^= 1;
        assert_ne!(digest(&r), d);
        let mut r = result(7);
        r.rays = 11; // not part of the image
        assert_eq!(digest(&r), d);
    }

    #[test]
    fn answers_that_never_agree_are_undecidable() {
        let mut c = Check::default();
        for w in 0..MAX_ANSWERS as u64 - 1 {
            assert_eq!(c.add(w, &result(w as i128)), Outcome::Open);
        }
        assert_eq!(c.add(99, &result(99)), Outcome::Undecidable);
    }

    #[test]
    fn the_checked_fraction_is_as_asked_and_first_results_are_all_checked() {
        let p = Policy::new(0.02, 4).unwrap();
        let n = 200_000u64;
        let checked = (0..n).filter(|&u| p.must_check(100, "job-1", u)).count() as f64;
        // Binomial: sd = sqrt(n p (1-p)) ≈ 62.6; allow 5 sd.
        assert!((checked - 4000.0).abs() < 5.0 * 62.61, "{checked}");
        assert!((0..4).all(|k| p.must_check(k, "job-1", 12345)));
        assert!(!Policy::default().must_check(0, "job-1", 1));
        assert!(Policy::new(1.5, 0).is_err());
        // Another key chooses other units.
        let q = Policy::new(0.02, 4).unwrap();
        let same = (0..n).filter(|&u| p.must_check(100, "j", u) == q.must_check(100, "j", u)).count();
        assert!(same < n as usize);
    }
}
