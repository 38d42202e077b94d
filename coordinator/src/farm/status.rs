//! What a job's status says — the farm's answer to "how is my job doing", which the
//! edge sends as `proto::JobStatus` and the commands show.

use super::job::{Job, JobPhase};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JobState {
    /// A frame waiting for earlier frames of its group.
    Queued,
    Loading,
    Running,
    Done,
    Failed,
    Cancelled,
}

impl JobState {
    /// Done, failed or cancelled: nothing more will happen to the job.
    pub fn is_final(self) -> bool {
        matches!(self, JobState::Done | JobState::Failed | JobState::Cancelled)
    }

    pub fn name(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Loading => "loading",
            JobState::Running => "running",
            JobState::Done => "done",
            JobState::Failed => "failed",
            JobState::Cancelled => "cancelled",
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct JobStatus {
    pub job_id: String,
    pub state: JobState,
    /// Why the job failed (empty otherwise).
    pub error: String,
    pub units_done: u64,
    pub units_total: u64,
    pub samples_done: u64,
    pub samples_total: u64,
    /// Live workers of the farm.
    pub workers: u32,
    pub width: u32,
    pub height: u32,
    /// The job's name.
    pub scene: String,
    pub elapsed_s: f64,
    /// From submission until the first unit began rendering: checking and loading.
    pub load_s: f64,
    /// From the first unit's start to the end (or now): what the rates are of.
    pub render_s: f64,
    pub rays: u64,
    /// Over the last few seconds, while the job runs (0 otherwise).
    pub samples_per_s: f64,
    /// The scene's warnings, bounded, and events such as a quarantine.
    pub warnings: Vec<String>,
    /// Units merged once a second worker agreed bit for bit.
    pub units_checked: u64,
    /// Units thrown away because their worker was caught lying.
    pub units_discarded: u64,
    /// Its weight in the fair share of workers (`schedule`).
    pub priority: u32,
    /// Gets no new units until resumed.
    pub paused: bool,
    /// Who submitted it (empty: an admin, or a farm without users).
    pub owner: String,
    /// When it was submitted, in seconds since the Unix epoch.
    pub submitted_unix_s: f64,
    /// The job group (an animation) it is a frame of; empty: none.
    pub group: String,
}

pub fn status_of(j: &Job, workers: usize) -> JobStatus {
    let (state, error) = match &j.phase {
        JobPhase::Queued => (JobState::Queued, String::new()),
        JobPhase::Loading => (JobState::Loading, String::new()),
        JobPhase::Running => (JobState::Running, String::new()),
        JobPhase::Done => (JobState::Done, String::new()),
        JobPhase::Failed(e) => (JobState::Failed, e.clone()),
        JobPhase::Cancelled => (JobState::Cancelled, String::new()),
    };
    JobStatus {
        job_id: j.id.clone(),
        state,
        error,
        units_done: j.units_done,
        units_total: j.units_total(),
        samples_done: j.samples_done,
        samples_total: j.samples_total(),
        workers: workers as u32,
        width: j.width,
        height: j.height,
        scene: j.name.clone(),
        elapsed_s: j.elapsed().as_secs_f64(),
        load_s: j.load_time().as_secs_f64(),
        render_s: j.render_time().as_secs_f64(),
        rays: j.rays,
        samples_per_s: if j.phase == JobPhase::Running { j.samples_per_second() } else { 0.0 },
        warnings: j.warnings.clone(),
        units_checked: j.units_checked,
        units_discarded: j.units_discarded,
        priority: j.share.priority,
        paused: j.share.paused,
        owner: j.owner.clone().unwrap_or_default(),
        submitted_unix_s: j.submitted_at.duration_since(std::time::UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64()),
        group: j.group.clone().unwrap_or_default(),
    }
}
