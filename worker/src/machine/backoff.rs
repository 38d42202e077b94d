//! Exponential backoff with jitter: 100 ms doubling up to a cap, each delay drawn
//! uniformly from its upper half, so workers that lost their coordinator together do
//! not all call again in the same instant when it returns.

use std::time::Duration;

#[derive(Clone, Debug)]
pub struct Backoff {
    next: Duration,
    max: Duration,
    /// xorshift64 state (never 0).
    rng: u64,
}

impl Backoff {
    pub const INITIAL: Duration = Duration::from_millis(100);

    /// Seeded from the clock and the process id: a different sequence per worker.
    pub fn new(max: Duration) -> Self {
        let t = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
        Self::with_seed(max, t.as_nanos() as u64 ^ (u64::from(std::process::id()) << 32))
    }

    pub fn with_seed(max: Duration, seed: u64) -> Self {
        let max = max.max(Duration::from_millis(1));
        // SplitMix64 of the seed, so that near seeds give unrelated sequences.
        let mut z = seed.wrapping_add(0x9e37_79b9_7f4a_7c15);
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        Self { next: Self::INITIAL.min(max), max, rng: (z ^ (z >> 31)) | 1 }
    }

    /// The delay before the next attempt: within the upper half of a base that doubles
    /// with each call, up to the cap.
    pub fn next_delay(&mut self) -> Duration {
        let base = self.next;
        self.next = (self.next * 2).min(self.max);
        self.rng ^= self.rng << 13;
        self.rng ^= self.rng >> 7;
        self.rng ^= self.rng << 17;
        let u = (self.rng >> 11) as f64 / (1u64 << 53) as f64;
        base.mul_f64(0.5 + 0.5 * u)
    }

    pub fn reset(&mut self) {
        self.next = Self::INITIAL.min(self.max);
    }

    /// Whether no failure has come since the last reset.
    pub fn is_reset(&self) -> bool {
        self.next == Self::INITIAL.min(self.max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn delays_double_up_to_the_cap_within_their_upper_half() {
        let mut b = Backoff::with_seed(Duration::from_millis(1000), 7);
        for base in [100, 200, 400, 800, 1000, 1000, 1000] {
            let d = b.next_delay().as_secs_f64() * 1000.0;
            assert!((base as f64 / 2.0..=base as f64).contains(&d), "{d} ms for a base of {base} ms");
        }
        b.reset();
        assert!(b.next_delay() <= Duration::from_millis(100));
        let mut tiny = Backoff::with_seed(Duration::from_millis(30), 7);
        assert!(tiny.next_delay() <= Duration::from_millis(30));
    }

    /// Two workers that fail together spread their retries.
    #[test]
    fn jitter_spreads_workers_apart() {
        let delays = |seed| {
            let mut b = Backoff::with_seed(Duration::from_secs(10), seed);
            (0..8).map(|_| b.next_delay()).collect::<Vec<_>>()
        };
        assert_ne!(delays(1), delays(2));
        let many: std::collections::BTreeSet<Duration> =
            (0..100).map(|s| Backoff::with_seed(Duration::from_secs(10), s).next_delay()).collect();
        assert!(many.len() > 90, "only {} distinct first delays of 100", many.len());
    }
}
