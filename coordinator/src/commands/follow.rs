//! The one loop that follows a job to its end — for `render` (its own job, in this
//! process), and for `submit --wait` and `fetch` (a farm's job, over gRPC): the progress
//! bar and the job's warnings, a PNG preview every few seconds, and Ctrl-C. What a
//! command does with the end is its own.

use std::path::Path;
use std::time::{Duration, Instant};

use tracer::film::Image;

use crate::commands::progress::JobBar;
use crate::farm::status::{JobState, JobStatus};

/// Where a followed job's news comes from.
pub trait JobFeed {
    /// The job's next status (when it changes, or after a short wait); `None` when the
    /// feed has closed.
    async fn next_status(&mut self) -> anyhow::Result<Option<JobStatus>>;

    /// The job's image so far.
    async fn image(&mut self) -> anyhow::Result<Image>;

    /// After each status that is not final: the feed's own upkeep (a render's
    /// checkpoints, its workers' health). An error stops following.
    async fn tick(&mut self, _status: &JobStatus, _bar: &JobBar) -> anyhow::Result<()> {
        Ok(())
    }
}

/// How following ended.
pub enum Followed {
    /// The job reached a final state (done, failed or cancelled).
    Ended(Box<JobStatus>),
    /// Ctrl-C or SIGTERM.
    Interrupted,
}

/// Follows `feed` until the job ends or the user interrupts, keeping `bar` and the
/// preview (rewritten every few seconds while the job runs) up to date.
pub async fn follow(feed: &mut impl JobFeed, bar: &mut JobBar, preview: Option<&Path>) -> anyhow::Result<Followed> {
    let stop = crate::stop_signal();
    tokio::pin!(stop);
    let mut last_preview = Instant::now();
    let mut last = None;
    loop {
        let next = tokio::select! {
            _ = &mut stop => return Ok(Followed::Interrupted),
            s = feed.next_status() => s?,
        };
        let Some(status) = next else {
            return last
                .map(|s| Followed::Ended(Box::new(s)))
                .ok_or_else(|| anyhow::anyhow!("the job's progress stream closed early"));
        };
        bar.update(&status);
        if status.state.is_final() {
            return Ok(Followed::Ended(Box::new(status)));
        }
        feed.tick(&status, bar).await?;
        if let Some(p) = preview
            && status.state == JobState::Running
            && last_preview.elapsed() > Duration::from_secs(3)
        {
            let written = feed.image().await.and_then(|image| Ok(tracer::output::write_png(&image, p)?));
            if let Err(e) = written {
                bar.warn(&format!("preview not written: {e:#}"));
            }
            last_preview = Instant::now();
        }
        last = Some(status);
    }
}
