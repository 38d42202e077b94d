//! When each unit's lease lapses, and which units have been out longest: kept in order,
//! so that reaping lapsed leases costs what lapses, and finding a straggler costs what
//! is looked at, not every unit of the job on every lease request.
//!
//! Entries are never updated in place: a renewal or a new lease adds one, and an entry
//! that no longer matches its unit's lease (renewed, done, handed over) is dropped when
//! it comes up. The job stays the one truth; this only orders it.

use std::cmp::Reverse;
use std::collections::{BTreeSet, BinaryHeap};
use std::time::Instant;

/// Which lease of a unit a deadline is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Slot {
    Primary,
    Spare,
}

/// Leases of units named by `Id` (a job's unit index).
pub struct LeaseClock<Id> {
    deadlines: BinaryHeap<Reverse<(Instant, Id, Slot)>>,
    /// Primary leases by the time they were made (or handed over).
    out_since: BTreeSet<(Instant, Id)>,
}

impl<Id> Default for LeaseClock<Id> {
    fn default() -> Self {
        Self { deadlines: BinaryHeap::new(), out_since: BTreeSet::new() }
    }
}

impl<Id: Ord + Copy> LeaseClock<Id> {
    /// A primary lease of `unit` made at `since`, lapsing at `deadline`.
    pub fn leased(&mut self, unit: Id, since: Instant, deadline: Instant) {
        self.deadlines.push(Reverse((deadline, unit, Slot::Primary)));
        self.out_since.insert((since, unit));
    }

    /// A lease's deadline moved (a renewal, or a spare made).
    pub fn deadline(&mut self, unit: Id, slot: Slot, deadline: Instant) {
        self.deadlines.push(Reverse((deadline, unit, slot)));
    }

    /// The primary lease made at `since` ended (done, lapsed, released).
    pub fn ended(&mut self, unit: Id, since: Instant) {
        self.out_since.remove(&(since, unit));
    }

    /// The next deadline at or before `now`, removed; stale ones come up too, and the
    /// caller checks each against its unit.
    pub fn pop_due(&mut self, now: Instant) -> Option<(Instant, Id, Slot)> {
        match self.deadlines.peek() {
            Some(Reverse((d, _, _))) if *d <= now => self.deadlines.pop().map(|Reverse(e)| e),
            _ => None,
        }
    }

    /// Primary leases, oldest first: `(since, unit)`.
    pub fn oldest_out(&self) -> impl Iterator<Item = (Instant, Id)> + '_ {
        self.out_since.iter().copied()
    }

    /// How many primary leases are out.
    pub fn out(&self) -> usize {
        self.out_since.len()
    }

    pub fn clear(&mut self) {
        self.deadlines.clear();
        self.out_since.clear();
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;

    #[test]
    fn deadlines_come_due_in_order_and_leases_oldest_first() {
        let t = Instant::now();
        let s = |ms| t + Duration::from_millis(ms);
        let mut c = LeaseClock::<u64>::default();
        c.leased(1, s(0), s(30));
        c.leased(2, s(5), s(10));
        c.deadline(1, Slot::Spare, s(20));
        assert_eq!(c.pop_due(s(9)), None);
        assert_eq!(c.pop_due(s(25)), Some((s(10), 2, Slot::Primary)));
        assert_eq!(c.pop_due(s(25)), Some((s(20), 1, Slot::Spare)));
        assert_eq!(c.pop_due(s(25)), None);
        assert_eq!(c.oldest_out().collect::<Vec<_>>(), [(s(0), 1), (s(5), 2)]);
        c.ended(1, s(0));
        assert_eq!(c.oldest_out().collect::<Vec<_>>(), [(s(5), 2)]);
    }
}
