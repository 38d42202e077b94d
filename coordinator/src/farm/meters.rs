//! What the farm counts for its metrics. Unit events are plain counters kept with the
//! state they describe (under the farm's lock, summed over jobs when asked, so that they
//! equal the jobs' own totals); the merge latency and the bytes moved are Prometheus
//! types, observed where they happen and exposed by the HTTP side (`edge::http`).

use prometheus::{Histogram, HistogramOpts, IntCounter};

/// Units by what happened to them, since the farm started: monotonic.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UnitCounters {
    /// Handed to a worker (a re-lease after a lapse, or a speculative copy, counts again).
    pub leased: u64,
    /// Merged into their job's image.
    pub completed: u64,
    /// Leases that ran out before their result came (the unit went back to the queue).
    pub lapsed: u64,
    /// Results refused (malformed, not the sender's, the job not running).
    pub rejected: u64,
    /// Merged once a second worker's render agreed bit for bit.
    pub verified: u64,
    /// Checks whose answers disagreed (a worker was caught, or none could be trusted).
    pub mismatched: u64,
}

impl UnitCounters {
    /// The counts that jobs keep, of one job.
    pub fn of_job(j: &super::job::Job) -> Self {
        Self { completed: j.merged, verified: j.units_checked, mismatched: j.units_mismatched, ..Self::default() }
    }

    pub fn add(&mut self, o: &Self) {
        self.leased += o.leased;
        self.completed += o.completed;
        self.lapsed += o.lapsed;
        self.rejected += o.rejected;
        self.verified += o.verified;
        self.mismatched += o.mismatched;
    }
}

/// Measured outside the farm's state.
pub struct Meters {
    /// From a batch of results reaching the farm (before its lock) to each one merged.
    pub merge_seconds: Histogram,
    /// Unit results, uploads received; assets and images sent.
    pub bytes_in: IntCounter,
    pub bytes_out: IntCounter,
}

impl Default for Meters {
    fn default() -> Self {
        let buckets = prometheus::exponential_buckets(1e-5, 4.0, 11).expect("valid buckets");
        let opts = HistogramOpts::new(
            "tilefarm_merge_seconds",
            "Time from a batch of unit results reaching the coordinator to each one merged",
        )
        .buckets(buckets);
        Self {
            merge_seconds: Histogram::with_opts(opts).expect("valid histogram"),
            bytes_in: IntCounter::new("tilefarm_bytes_in_total", "Bytes received: unit results and uploads")
                .expect("valid counter"),
            bytes_out: IntCounter::new("tilefarm_bytes_out_total", "Bytes sent: assets to workers and images")
                .expect("valid counter"),
        }
    }
}
