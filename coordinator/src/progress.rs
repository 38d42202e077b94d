//! The progress bar of `render` and `submit --wait`: tiles and samples done, samples/s,
//! ETA and workers connected.

use indicatif::{ProgressBar, ProgressStyle};

pub struct JobBar {
    bar: ProgressBar,
}

impl JobBar {
    pub fn new(quiet: bool) -> Self {
        let bar = if quiet { ProgressBar::hidden() } else { ProgressBar::new(1) };
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {wide_bar} {percent:>3}% {msg} {per_sec} ETA {eta}",
            )
            .expect("static template"),
        );
        Self { bar }
    }

    pub fn update(&self, s: &proto::JobStatus) {
        self.bar.set_length(s.samples_total.max(1));
        self.bar.set_position(s.samples_done);
        self.bar.set_message(format!("units {}/{} · workers {}", s.units_done, s.units_total, s.workers));
    }

    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

/// The closing line of a finished job; `earlier` are the samples (and rays) that a
/// checkpoint already held, which this run's speed must not count.
pub fn summary(s: &proto::JobStatus, earlier_samples: u64, earlier_rays: u64) -> String {
    let secs = s.elapsed_s.max(1e-9);
    let (samples, rays) = (s.samples_done.saturating_sub(earlier_samples), s.rays.saturating_sub(earlier_rays));
    format!(
        "rendered {}×{} ({samples} samples) in {:.2}s: {:.3} M samples/s, {:.3} M rays/s",
        s.width,
        s.height,
        secs,
        samples as f64 / secs / 1e6,
        rays as f64 / secs / 1e6
    )
}
