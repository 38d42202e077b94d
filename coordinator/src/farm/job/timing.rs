//! A job's clock: how long it loaded (its scene checked here, then loaded by the
//! workers) and how long it rendered, told apart by the render time each result carries.

use std::time::{Duration, Instant};

use super::Job;

impl Job {
    /// A result that took `seconds` to render arrived `now`: rendering began no later.
    pub(super) fn rendered(&mut self, now: Instant, seconds: f64) {
        let began = now.checked_sub(Duration::from_secs_f64(seconds.max(0.0))).unwrap_or(now).max(self.started);
        self.rendering_since = Some(self.rendering_since.map_or(began, |s| s.min(began)));
    }

    /// Samples merged per second since the job started (or was restored: the samples a
    /// checkpoint brought do not count).
    pub fn samples_per_second(&self) -> f64 {
        let secs = self.elapsed().as_secs_f64();
        if secs > 0.0 { self.samples_done.saturating_sub(self.samples_at_start) as f64 / secs } else { 0.0 }
    }

    /// Since the job (or its restore) started, after its scene was checked.
    pub fn elapsed(&self) -> Duration {
        self.end().saturating_duration_since(self.started)
    }

    /// From submission until the first unit began rendering (until now, or the end, if
    /// none has): the coordinator's check of the scene and the workers' loading.
    pub fn load_time(&self) -> Duration {
        self.rendering_since.unwrap_or_else(|| self.end()).saturating_duration_since(self.submitted)
    }

    /// From the first unit's start to the end (or now); zero before any result.
    pub fn render_time(&self) -> Duration {
        self.rendering_since.map_or(Duration::ZERO, |s| self.end().saturating_duration_since(s))
    }

    fn end(&self) -> Instant {
        self.finished.unwrap_or_else(Instant::now)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::farm::job::tests::{NEVER, job, result_for};

    /// Loading lasts until the first unit began rendering, by the results' own render
    /// times: a result that took 2 s and arrived at 5 s means rendering began at 3 s.
    #[test]
    fn loading_ends_where_the_first_unit_began_rendering() {
        let mut j = job();
        let t0 = j.started;
        let lease = |j: &mut Job| j.lease_next(1, t0, t0 + NEVER, NEVER).unwrap();
        j.submitted = t0 - Duration::from_secs(1);
        assert_eq!(j.render_time(), Duration::ZERO);
        let u = lease(&mut j);
        let mut r = result_for(&j, u, 1);
        r.render_seconds = 2.0;
        j.apply_at(1, &r, t0 + Duration::from_secs(5), false).unwrap();
        let u = lease(&mut j);
        let mut r = result_for(&j, u, 1);
        r.render_seconds = 0.5;
        j.apply_at(1, &r, t0 + Duration::from_secs(4), false).unwrap();
        assert_eq!(j.rendering_since, Some(t0 + Duration::from_secs(3)), "the earliest start");
        assert_eq!(j.load_time(), Duration::from_secs(4));
        // A render time longer than the job has run cannot start before the job did.
        let u = lease(&mut j);
        let mut r = result_for(&j, u, 1);
        r.render_seconds = 1e6;
        j.apply_at(1, &r, t0 + Duration::from_secs(6), false).unwrap();
        assert_eq!(j.rendering_since, Some(t0));
    }
}
