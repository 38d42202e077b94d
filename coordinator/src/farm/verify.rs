//! Verified results. A unit's result is a pure function of (scene, unit), so two honest
//! workers return the same bits. A unit chosen for checking is not merged on its first
//! answer: it is rendered again under a different *identity* (another certificate or
//! token, or the coordinator itself), and merged only once answers of two identities
//! agree bit for bit. An identity answers a check once, however many workers it has
//! registered, so its workers cannot vouch for each other. Any answer that differs from
//! the agreed one came from an identity that lied (or is broken), which the farm bans.
//!
//! Which units are checked is decided with a key only the coordinator knows, so a
//! worker cannot tell a checked unit from any other; how many, by the identity's record
//! (see [`Policy::check_rate`]).

use sha2::{Digest, Sha256};

use proto::domain::UnitResult;

use super::ids::{By, IdentityId, UnitId};

/// Most answers one unit collects before two agree: with honest identities it takes
/// two; more means several identities disagree with each other.
pub const MAX_ANSWERS: usize = 5;

/// One identity's answer for a unit under check (returned by one of its workers).
#[derive(Clone, Debug)]
pub struct Answer {
    pub by: By,
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
    /// No two answers agree yet: another identity must render the unit.
    Open,
    /// Two identities' answers agree: merge answer `agreed`; `liars` answered otherwise.
    Settled { agreed: usize, liars: Vec<IdentityId> },
    /// [`MAX_ANSWERS`] answers and no two agree: nothing can be trusted.
    Undecidable,
}

impl Check {
    /// Has `identity` (through any of its workers) answered?
    pub fn answered(&self, identity: IdentityId) -> bool {
        self.answers.iter().any(|a| a.by.identity == identity)
    }

    /// Adds the answer of `by`, whose identity has not answered yet (the caller made
    /// sure), and says what it settled.
    pub fn add(&mut self, by: By, result: &UnitResult) -> Outcome {
        debug_assert!(!self.answered(by.identity));
        self.answers.push(Answer { by, digest: digest(result), result: result.clone() });
        self.outcome()
    }

    /// Settled once two answers agree: each identity answers once, so two agreeing
    /// answers are two identities'.
    fn outcome(&self) -> Outcome {
        for (i, a) in self.answers.iter().enumerate() {
            if self.answers[i + 1..].iter().any(|b| b.digest == a.digest) {
                let liars = self.answers.iter().filter(|b| b.digest != a.digest).map(|b| b.by.identity).collect();
                return Outcome::Settled { agreed: i, liars };
            }
        }
        if self.answers.len() >= MAX_ANSWERS { Outcome::Undecidable } else { Outcome::Open }
    }

    /// Forgets a banned identity's answer.
    pub fn drop_identity(&mut self, identity: IdentityId) {
        self.answers.retain(|a| a.by.identity != identity);
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

/// Which units to check: a secret key, the fraction checked of an identity with a long
/// honest record, and the probation of a new one.
#[derive(Clone)]
pub struct Policy {
    key: [u8; 32],
    /// Fraction of units checked at the least, 0 to 1 (0: no checks at all).
    pub fraction: f64,
    /// Every result of an identity's first this-many is checked; after them the rate
    /// falls as `probation / record` until it reaches `fraction` (see [`Policy::check_rate`]).
    pub probation: u64,
}

impl std::fmt::Debug for Policy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Policy {{ fraction: {}, probation: {} }}", self.fraction, self.probation)
    }
}

impl Default for Policy {
    /// No checks (a local render's own workers).
    fn default() -> Self {
        Self { key: [0; 32], fraction: 0.0, probation: 0 }
    }
}

impl Policy {
    /// Checks at least `fraction` of units, and more of an identity with a short record,
    /// choosing with a fresh random key.
    pub fn new(fraction: f64, probation: u64) -> Result<Self, String> {
        if !(0.0..=1.0).contains(&fraction) {
            return Err(format!("--verify {fraction}: a fraction between 0 and 1"));
        }
        let mut key = [0u8; 32];
        getrandom::fill(&mut key).map_err(|e| format!("no randomness for choosing checked units: {e}"))?;
        Ok(Self { key, fraction, probation })
    }

    pub fn enabled(&self) -> bool {
        self.fraction > 0.0
    }

    /// The chance that a result is checked, for an identity that has had `record`
    /// results taken before it: 1 during probation, then `probation / record`, never
    /// below `fraction`. A new identity is checked until it has a record; one with a
    /// long honest record costs the farm little more than `fraction`.
    pub fn check_rate(&self, record: u64) -> f64 {
        if !self.enabled() {
            0.0
        } else if record < self.probation {
            1.0
        } else {
            (self.probation as f64 / record.max(1) as f64).clamp(self.fraction, 1.0)
        }
    }

    /// The chance that `lies` wrong results, returned one after another by an identity
    /// with `record` results taken before them, all go unchecked: the product of
    /// `1 - check_rate` over them (README.md's security section states it).
    pub fn escape_chance(&self, record: u64, lies: u64) -> f64 {
        (record..record + lies).map(|r| 1.0 - self.check_rate(r)).product()
    }

    /// Is this result to be checked? `record` counts its identity's earlier results.
    pub fn must_check(&self, record: u64, job: &str, unit: UnitId) -> bool {
        let rate = self.check_rate(record);
        if rate <= 0.0 || rate >= 1.0 {
            return rate >= 1.0;
        }
        let mut h = Sha256::new();
        h.update(self.key);
        h.update(job.as_bytes());
        h.update(unit.to_le_bytes());
        let x = u64::from_le_bytes(h.finalize()[..8].try_into().expect("8 bytes"));
        (x as f64) < rate * 18_446_744_073_709_551_616.0
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
        assert_eq!(c.add(1.into(), &result(7)), Outcome::Open);
        assert_eq!(c.add(2.into(), &result(8)), Outcome::Open, "two answers that differ need a third");
        assert_eq!(c.add(3.into(), &result(7)), Outcome::Settled { agreed: 0, liars: vec![2] });
        let mut c = Check::default();
        c.add(1.into(), &result(9));
        assert_eq!(c.add(2.into(), &result(7)), Outcome::Open);
        assert_eq!(c.add(3.into(), &result(7)), Outcome::Settled { agreed: 1, liars: vec![1] });
        assert!(c.answered(1) && !c.answered(4));
        c.drop_identity(1);
        assert_eq!(c.answers.len(), 2);
    }

    #[test]
    fn an_identity_is_one_answer_whichever_of_its_workers_answers() {
        let mut c = Check::default();
        c.add(By { worker: 10, identity: 1 }, &result(0));
        assert!(c.answered(1), "another worker of identity 1 has nothing to add");
        assert_eq!(c.add(By { worker: 20, identity: 2 }, &result(7)), Outcome::Open);
        let settled = c.add(By { worker: 30, identity: 3 }, &result(7));
        assert_eq!(settled, Outcome::Settled { agreed: 1, liars: vec![1] });
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
            assert_eq!(c.add(w.into(), &result(w as i128)), Outcome::Open);
        }
        assert_eq!(c.add(99.into(), &result(99)), Outcome::Undecidable);
    }

    #[test]
    fn the_checked_fraction_is_as_asked_and_first_results_are_all_checked() {
        let p = Policy::new(0.02, 4).unwrap();
        let n = 200_000u64;
        let checked = (0..n).filter(|&u| p.must_check(1000, "job-1", u)).count() as f64;
        // Binomial: sd = sqrt(n p (1-p)) ≈ 62.6; allow 5 sd.
        assert!((checked - 4000.0).abs() < 5.0 * 62.61, "{checked}");
        assert!((0..4).all(|k| p.must_check(k, "job-1", 12345)));
        assert!(!Policy::default().must_check(0, "job-1", 1));
        assert!(Policy::new(1.5, 0).is_err());
        // Another key chooses other units.
        let q = Policy::new(0.02, 4).unwrap();
        let same = (0..n).filter(|&u| p.must_check(1000, "j", u) == q.must_check(1000, "j", u)).count();
        assert!(same < n as usize);
    }

    #[test]
    fn the_check_rate_falls_with_the_record_to_the_fraction() {
        let p = Policy::new(0.02, 16).unwrap();
        assert_eq!((p.check_rate(0), p.check_rate(15)), (1.0, 1.0), "probation");
        assert_eq!((p.check_rate(16), p.check_rate(32), p.check_rate(160)), (1.0, 0.5, 0.1));
        assert_eq!((p.check_rate(800), p.check_rate(100_000)), (0.02, 0.02));
        // Measured against the rate it states, 5 sd of a binomial.
        let n = 100_000u64;
        let checked = (0..n).filter(|&u| p.must_check(64, "job-7", u)).count() as f64;
        assert!((checked - 25_000.0).abs() < 5.0 * (n as f64 * 0.25 * 0.75).sqrt(), "{checked}");
        // Five lies after four honest results are all checked; after a long record,
        // each escapes with 1 - fraction.
        assert_eq!(p.escape_chance(4, 5), 0.0);
        assert!((p.escape_chance(10_000, 5) - 0.98f64.powi(5)).abs() < 1e-12);
        assert_eq!(Policy::default().check_rate(0), 0.0);
    }
}
