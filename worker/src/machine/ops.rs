//! One kind of repeated call (register, lease, heartbeat): at most one in flight, the
//! next not before `next_at`, failures spaced by a backoff.

use std::time::{Duration, Instant};

use super::backoff::Backoff;

pub(super) struct Op {
    pub in_flight: bool,
    pub next_at: Instant,
    pub backoff: Backoff,
}

impl Op {
    pub fn new(now: Instant, max_backoff: Duration) -> Self {
        Self { in_flight: false, next_at: now, backoff: Backoff::new(max_backoff) }
    }

    pub fn due(&self, now: Instant) -> bool {
        !self.in_flight && now >= self.next_at
    }

    /// After a success: go again at `next`, with the backoff reset.
    pub fn succeeded(&mut self, next: Instant) {
        self.in_flight = false;
        self.backoff.reset();
        self.next_at = next;
    }

    /// Go again now rather than at a later time set by an idle answer: when something
    /// that may have made work (results merged) happened. Not while failing: a backoff
    /// stays in force.
    pub fn hurry(&mut self, now: Instant) {
        if !self.in_flight && self.backoff.is_reset() {
            self.next_at = self.next_at.min(now);
        }
    }

    /// After a failure: go again after the backoff's next delay (at most `cap`).
    pub fn failed(&mut self, now: Instant, cap: Option<Duration>) -> Duration {
        self.in_flight = false;
        let mut d = self.backoff.next_delay();
        if let Some(cap) = cap {
            d = d.min(cap);
        }
        self.next_at = now + d;
        d
    }
}
