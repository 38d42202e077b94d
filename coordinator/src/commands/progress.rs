//! The progress bar of `render`, `submit --wait` and `fetch`: samples done, the rate in
//! samples per second, ETA, units and workers; and the closing summary line.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};

use crate::farm::status::{JobState, JobStatus};

pub struct JobBar {
    bar: ProgressBar,
    rate: Rate,
    /// The job's scene warnings have been printed.
    warned: bool,
    /// Where standard error is not a terminal (a log, a pipe read by another program such
    /// as the Blender add-on), the bar cannot draw: progress goes there as plain lines.
    lines: Option<Lines>,
}

/// The plain progress lines' pace: one when the whole percent changes, at most one a
/// second (a long job writes at most about a hundred).
#[derive(Default)]
struct Lines {
    last: Option<(Instant, u64)>,
}

impl Lines {
    const EVERY: Duration = Duration::from_secs(1);

    fn due(&mut self, now: Instant, percent: u64) -> bool {
        let due = match self.last {
            None => true,
            Some((at, p)) => p != percent && now.duration_since(at) >= Self::EVERY,
        };
        if due {
            self.last = Some((now, percent));
        }
        due
    }
}

impl JobBar {
    pub fn new(quiet: bool) -> Self {
        use std::io::IsTerminal;
        let bar = if quiet { ProgressBar::hidden() } else { ProgressBar::new(1) };
        bar.set_style(
            ProgressStyle::with_template("{spinner} [{elapsed_precise}] {wide_bar} {percent:>3}% {msg}")
                .expect("static template"),
        );
        bar.enable_steady_tick(Duration::from_millis(250));
        let lines = (!quiet && !std::io::stderr().is_terminal()).then(Lines::default);
        Self { bar, rate: Rate::default(), warned: false, lines }
    }

    pub fn update(&mut self, s: &JobStatus) {
        // The scene's problems, once, as soon as the job knows them (even with -q).
        if !self.warned && !s.warnings.is_empty() {
            for w in &s.warnings {
                self.warn(w);
            }
            self.warned = true;
        }
        let now = Instant::now();
        self.rate.observe(now, s.samples_done);
        self.bar.set_length(s.samples_total.max(1));
        self.bar.set_position(s.samples_done);
        let rate = self.rate.per_second();
        let eta = match rate {
            Some(r) if r > 0.0 => {
                format_duration(Duration::from_secs_f64(s.samples_total.saturating_sub(s.samples_done) as f64 / r))
            }
            _ => "?".into(),
        };
        let message = format!(
            "{} / {} samples · {} · ETA {eta} · units {}/{} · {} worker{}",
            si(s.samples_done as f64),
            si(s.samples_total as f64),
            rate.map_or_else(|| "– samples/s".to_string(), |r| format!("{}samples/s", si_unit(r))),
            s.units_done,
            s.units_total,
            s.workers,
            if s.workers == 1 { "" } else { "s" }
        );
        if let Some(lines) = &mut self.lines
            && s.samples_total > 0
        {
            let percent = s.samples_done * 100 / s.samples_total;
            if lines.due(now, percent) {
                eprintln!("progress: {percent}% · {message}");
            }
        }
        self.bar.set_message(message);
    }

    /// A warning printed above the bar (which is redrawn below it).
    pub fn warn(&self, message: &str) {
        self.bar.suspend(|| eprintln!("warning: {message}"));
    }

    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

/// The rate of samples over the last few seconds that this bar has seen: a job followed
/// from the middle (`fetch`) or resumed from a checkpoint shows its true speed, not the
/// samples it already had divided by a short time.
#[derive(Default)]
struct Rate {
    seen: VecDeque<(Instant, u64)>,
}

impl Rate {
    const WINDOW: Duration = Duration::from_secs(10);

    fn observe(&mut self, now: Instant, samples: u64) {
        if let Some(&(_, last)) = self.seen.back()
            && samples < last
        {
            self.seen.clear(); // a restarted job: start again
        }
        self.seen.push_back((now, samples));
        while self.seen.len() > 2 && now.duration_since(self.seen[1].0) >= Self::WINDOW {
            self.seen.pop_front();
        }
    }

    /// Samples per second; `None` until half a second has been seen.
    fn per_second(&self) -> Option<f64> {
        let (&(t0, s0), &(t1, s1)) = (self.seen.front()?, self.seen.back()?);
        let dt = t1.duration_since(t0).as_secs_f64();
        (dt >= 0.5).then(|| (s1 - s0) as f64 / dt)
    }
}

/// `1.23 M`, `512 k`, `17 `: a count with an SI prefix, three significant digits.
fn si_unit(x: f64) -> String {
    let (v, p) = match x {
        x if x >= 1e9 => (x / 1e9, "G"),
        x if x >= 1e6 => (x / 1e6, "M"),
        x if x >= 1e3 => (x / 1e3, "k"),
        x => (x, ""),
    };
    let digits = if v >= 100.0 {
        0
    } else if v >= 10.0 {
        1
    } else {
        2
    };
    format!("{v:.digits$} {p}")
}

fn si(x: f64) -> String {
    si_unit(x).trim_end().to_string()
}

fn format_duration(d: Duration) -> String {
    let s = d.as_secs();
    if s >= 3600 {
        format!("{}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
    } else {
        format!("{}:{:02}", s / 60, s % 60)
    }
}

/// A job as `status` lists it: id, state, name, size, samples, rate and ETA.
pub fn status_line(j: &JobStatus) -> String {
    let state = j.state.name();
    if j.state == JobState::Done && j.width == 0 {
        // A frame known only by its stored image (no longer listed): no size or samples.
        return format!("{:<8} {:<9} {:<20} image stored (`fetch {}` writes it)", j.job_id, state, j.scene, j.job_id);
    }
    let percent = 100.0 * j.samples_done as f64 / j.samples_total.max(1) as f64;
    let mut line = format!(
        "{:<8} {:<9} {:<20} {}×{}  {} / {} samples ({percent:.0}%)",
        j.job_id,
        state,
        j.scene,
        j.width,
        j.height,
        si(j.samples_done as f64),
        si(j.samples_total as f64)
    );
    if j.state == JobState::Running && j.samples_per_s > 0.0 {
        let left = j.samples_total.saturating_sub(j.samples_done) as f64 / j.samples_per_s;
        line += &format!(
            "  {}samples/s  ETA {}",
            si_unit(j.samples_per_s),
            format_duration(Duration::from_secs_f64(left.min(1e9)))
        );
    }
    if j.priority != crate::farm::schedule::DEFAULT_PRIORITY {
        line += &format!("  priority {}", j.priority);
    }
    if j.paused {
        line += "  PAUSED";
    }
    if j.units_checked > 0 || j.units_discarded > 0 {
        line += &format!("  {} units checked, {} discarded", j.units_checked, j.units_discarded);
    }
    if !j.error.is_empty() {
        line += &format!("  error: {}", j.error);
    }
    line
}

/// One line for a job group (an animation): its frames by state, its samples, and an
/// estimate of the time left (queued frames are taken to be as large as the loaded ones).
pub fn group_line(name: &str, frames: &[&JobStatus]) -> String {
    let count = |s: JobState| frames.iter().filter(|f| f.state == s).count();
    let states =
        [JobState::Done, JobState::Running, JobState::Loading, JobState::Queued, JobState::Cancelled, JobState::Failed];
    let parts: Vec<String> =
        states.iter().filter(|&&s| count(s) > 0).map(|&s| format!("{} {}", count(s), s.name())).collect();
    // Cancelled and failed frames will render no more: not counted.
    let live: Vec<&&JobStatus> =
        frames.iter().filter(|f| !matches!(f.state, JobState::Cancelled | JobState::Failed)).collect();
    let known: Vec<&&&JobStatus> = live.iter().filter(|f| f.samples_total > 0).collect();
    let done: u64 = live.iter().map(|f| f.samples_done).sum();
    let mut line = format!("group {name}: {} frames ({})", frames.len(), parts.join(", "));
    if !known.is_empty() {
        let per_frame = known.iter().map(|f| f.samples_total as f64).sum::<f64>() / known.len() as f64;
        let total = per_frame * live.len() as f64;
        line +=
            &format!("  {} / ~{} samples ({:.0}%)", si(done as f64), si(total), 100.0 * done as f64 / total.max(1.0));
        let rate: f64 = frames.iter().filter(|f| f.state == JobState::Running).map(|f| f.samples_per_s).sum();
        if rate > 0.0 {
            let left = (total - done as f64).max(0.0) / rate;
            line += &format!(
                "  {}samples/s  ETA ~{}",
                si_unit(rate),
                format_duration(Duration::from_secs_f64(left.min(1e9)))
            );
        }
    }
    line
}

/// The closing line of a finished job; `earlier` are the samples (and rays) that a
/// checkpoint already held, which this run's speed must not count.
pub fn summary(s: &JobStatus, earlier_samples: u64, earlier_rays: u64) -> String {
    // The rates are of the rendering alone, not of the scene's loading.
    let secs = if s.render_s > 0.0 { s.render_s } else { s.elapsed_s }.max(1e-9);
    let (samples, rays) = (s.samples_done.saturating_sub(earlier_samples), s.rays.saturating_sub(earlier_rays));
    format!(
        "loaded the scene in {:.2}s; rendered {}×{} ({samples} samples) in {:.2}s: {:.3} M samples/s, {:.3} M rays/s",
        s.load_s,
        s.width,
        s.height,
        secs,
        samples as f64 / secs / 1e6,
        rays as f64 / secs / 1e6
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rates_are_labelled_with_si_prefixes() {
        assert_eq!(si_unit(2_632_224.677), "2.63 M");
        assert_eq!(si_unit(512_000.0), "512 k");
        assert_eq!(si_unit(17.0), "17.0 ");
        assert_eq!(si(3.41e9), "3.41 G");
        assert_eq!(format_duration(Duration::from_secs(75)), "1:15");
        assert_eq!(format_duration(Duration::from_secs(3725)), "1:02:05");
    }

    /// A group's line: frames by state; samples and the time left counted over the frames
    /// that will still render, queued ones taken as large as the loaded ones.
    #[test]
    fn a_group_line_counts_what_is_left() {
        let frame = |state, done, total, rate| JobStatus {
            job_id: String::new(),
            state,
            error: String::new(),
            units_done: 0,
            units_total: 0,
            samples_done: done,
            samples_total: total,
            workers: 1,
            width: 0,
            height: 0,
            scene: String::new(),
            elapsed_s: 0.0,
            load_s: 0.0,
            render_s: 0.0,
            rays: 0,
            samples_per_s: rate,
            warnings: vec![],
            units_checked: 0,
            units_discarded: 0,
            priority: 50,
            paused: false,
            owner: String::new(),
            submitted_unix_s: 0.0,
            group: "g".into(),
        };
        let frames = [
            frame(JobState::Done, 1000, 1000, 0.0),
            frame(JobState::Running, 500, 1000, 10.0),
            frame(JobState::Queued, 0, 0, 0.0),
            frame(JobState::Cancelled, 200, 1000, 0.0),
        ];
        let line = group_line("g", &frames.iter().collect::<Vec<_>>());
        assert_eq!(
            line,
            "group g: 4 frames (1 done, 1 running, 1 queued, 1 cancelled)  1.50 k / ~3.00 k samples (50%)  \
             10.0 samples/s  ETA ~2:30"
        );
        let cancelled = [frame(JobState::Cancelled, 200, 1000, 0.0)];
        assert_eq!(group_line("g", &cancelled.iter().collect::<Vec<_>>()), "group g: 1 frames (1 cancelled)");
    }

    /// Plain progress lines: the first at once, then one per whole-percent change at
    /// most every second.
    #[test]
    fn plain_progress_lines_are_paced() {
        let mut l = Lines::default();
        let t = Instant::now();
        let s = Duration::from_millis;
        assert!(l.due(t, 0));
        assert!(!l.due(t + s(1500), 0), "no change");
        assert!(!l.due(t + s(1600) - s(700), 3), "too soon");
        assert!(l.due(t + s(1600), 3));
        assert!(!l.due(t + s(2000), 4));
        assert!(l.due(t + s(2700), 100));
    }

    /// A job followed from the middle: the samples it had before count for nothing.
    #[test]
    fn the_rate_is_what_was_seen_not_what_the_job_had() {
        let mut r = Rate::default();
        let t = Instant::now();
        r.observe(t, 1_000_000_000);
        assert_eq!(r.per_second(), None);
        r.observe(t + Duration::from_secs(1), 1_000_000_000 + 5_000);
        r.observe(t + Duration::from_secs(2), 1_000_000_000 + 10_000);
        assert_eq!(r.per_second(), Some(5_000.0));
        // Only the last ten seconds count.
        r.observe(t + Duration::from_secs(30), 1_000_000_000 + 10_000);
        r.observe(t + Duration::from_secs(31), 1_000_000_000 + 10_000);
        assert_eq!(r.per_second(), Some(0.0));
    }
}
