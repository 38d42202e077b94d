//! The mapping of the coordinator's own messages — a job's status, the farm's errors —
//! between the wire and the farm's types. Jobs' specs, units and results, which
//! workers share, are mapped in `proto::wire`.

use tonic::Status;

use crate::farm::FarmError;
use crate::farm::job::Rejection;
use crate::farm::status::{JobState, JobStatus};
use crate::farm::stored::StoredFrame;

/// Largest number of warnings a status from the wire may carry, and their length.
const MAX_WARNINGS: usize = 100;
const MAX_WARNING_CHARS: usize = 2000;
/// Longest owner name a status from the wire may carry.
const MAX_NAME_CHARS: usize = 200;

fn state_to_proto(s: JobState) -> proto::JobState {
    match s {
        JobState::Queued => proto::JobState::Queued,
        JobState::Loading => proto::JobState::Loading,
        JobState::Running => proto::JobState::Running,
        JobState::Done => proto::JobState::Done,
        JobState::Failed => proto::JobState::Failed,
        JobState::Cancelled => proto::JobState::Cancelled,
    }
}

pub fn status_to_proto(s: JobStatus) -> proto::JobStatus {
    proto::JobStatus {
        job_id: s.job_id,
        state: state_to_proto(s.state) as i32,
        error: s.error,
        units_done: s.units_done,
        units_total: s.units_total,
        samples_done: s.samples_done,
        samples_total: s.samples_total,
        workers: s.workers,
        width: s.width,
        height: s.height,
        scene: s.scene,
        elapsed_s: s.elapsed_s,
        load_s: s.load_s,
        render_s: s.render_s,
        rays: s.rays,
        samples_per_s: s.samples_per_s,
        warnings: s.warnings,
        units_checked: s.units_checked,
        units_discarded: s.units_discarded,
        priority: s.priority,
        paused: s.paused,
        owner: s.owner,
        submitted_unix_s: s.submitted_unix_s,
        group: s.group,
    }
}

/// A group's stored frame as the status of a done job: its id, name, group and owner.
pub fn stored_frame_to_proto(f: StoredFrame, group: &str) -> proto::JobStatus {
    proto::JobStatus {
        job_id: f.job,
        state: proto::JobState::Done as i32,
        scene: f.name,
        group: group.to_string(),
        owner: f.owner.unwrap_or_default(),
        ..Default::default()
    }
}

/// A job no longer listed whose image is stored: done; `name` is its frame name if it
/// was a group's frame (listed alone, not as its group's).
pub fn stored_job_to_proto(job: String, owner: Option<String>, name: Option<String>) -> proto::JobStatus {
    proto::JobStatus {
        job_id: job,
        state: proto::JobState::Done as i32,
        scene: name.unwrap_or_default(),
        owner: owner.unwrap_or_default(),
        ..Default::default()
    }
}

/// A status from a farm, checked: a known state, and warnings bounded in number and
/// length (they are printed).
pub fn status_from_proto(s: proto::JobStatus) -> Result<JobStatus, String> {
    let state = match proto::JobState::try_from(s.state) {
        Ok(proto::JobState::Queued) => JobState::Queued,
        Ok(proto::JobState::Loading) => JobState::Loading,
        Ok(proto::JobState::Running) => JobState::Running,
        Ok(proto::JobState::Done) => JobState::Done,
        Ok(proto::JobState::Failed) => JobState::Failed,
        Ok(proto::JobState::Cancelled) => JobState::Cancelled,
        _ => return Err(format!("job {}: unknown state {}", s.job_id, s.state)),
    };
    let warnings = s.warnings.into_iter().take(MAX_WARNINGS).map(|w| w.chars().take(MAX_WARNING_CHARS).collect());
    Ok(JobStatus {
        job_id: s.job_id,
        state,
        error: s.error,
        units_done: s.units_done,
        units_total: s.units_total,
        samples_done: s.samples_done,
        samples_total: s.samples_total,
        workers: s.workers,
        width: s.width,
        height: s.height,
        scene: s.scene,
        elapsed_s: seconds(s.elapsed_s),
        load_s: seconds(s.load_s),
        render_s: seconds(s.render_s),
        rays: s.rays,
        samples_per_s: if s.samples_per_s.is_finite() { s.samples_per_s.max(0.0) } else { 0.0 },
        warnings: warnings.collect(),
        units_checked: s.units_checked,
        units_discarded: s.units_discarded,
        priority: s.priority.min(crate::farm::schedule::MAX_PRIORITY),
        paused: s.paused,
        owner: s.owner.chars().take(MAX_NAME_CHARS).collect(),
        submitted_unix_s: seconds(s.submitted_unix_s),
        group: s.group.chars().take(proto::wire::MAX_GROUP_CHARS).collect(),
    })
}

/// A duration from the wire: finite and not negative (else 0).
fn seconds(s: f64) -> f64 {
    if s.is_finite() { s.max(0.0) } else { 0.0 }
}

/// The status code a farm error travels as, its message bounded.
pub fn error_to_status(e: FarmError) -> Status {
    let m = proto::wire::bounded(e.to_string());
    match e {
        FarmError::UnknownWorker(_) | FarmError::UnknownJob(_) => Status::not_found(m),
        FarmError::Invalid(_) | FarmError::Rejected(Rejection::UnknownUnit(_) | Rejection::Malformed { .. }) => {
            Status::invalid_argument(m)
        }
        FarmError::NotUploaded(_) | FarmError::Rejected(Rejection::NotHolder(..) | Rejection::NotRunning(_)) => {
            Status::failed_precondition(m)
        }
        FarmError::Forbidden(_) => Status::permission_denied(m),
        FarmError::Exhausted(_) => Status::resource_exhausted(m),
    }
}

/// A message that did not decode, as the client is told: its message bounded.
pub fn invalid(message: String) -> Status {
    Status::invalid_argument(proto::wire::bounded(message))
}

/// The farm's identities as an admin sees them.
pub fn identities_to_proto(farm: &crate::farm::Farm) -> Vec<proto::IdentityInfo> {
    let since = |t: std::time::SystemTime| t.duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs());
    farm.identities
        .iter()
        .map(|i| proto::IdentityInfo {
            name: i.name.clone(),
            answers: i.answers,
            refused: i.refused,
            banned: i.banned.is_some(),
            ban_reason: i.banned.as_ref().map_or_else(String::new, |b| b.reason.clone()),
            banned_at_unix_s: i.banned.as_ref().map_or(0, |b| since(b.at)),
            workers: farm.workers.values().filter(|w| w.trust == i.id).count() as u32,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn status(state: JobState) -> JobStatus {
        JobStatus {
            job_id: "job-3".into(),
            state,
            error: String::new(),
            units_done: 4,
            units_total: 9,
            samples_done: 400,
            samples_total: 900,
            workers: 2,
            width: 30,
            height: 30,
            scene: "cornell".into(),
            elapsed_s: 1.5,
            load_s: 0.25,
            render_s: 1.25,
            rays: 1234,
            samples_per_s: 266.0,
            warnings: vec!["quad.mtl: 1 face skipped".into()],
            units_checked: 3,
            units_discarded: 1,
            priority: 70,
            paused: true,
            owner: "ana".into(),
            submitted_unix_s: 1.8e9,
            group: "shot".into(),
        }
    }

    #[test]
    fn a_status_round_trips() {
        for state in [
            JobState::Queued,
            JobState::Loading,
            JobState::Running,
            JobState::Done,
            JobState::Failed,
            JobState::Cancelled,
        ] {
            let s = status(state);
            assert_eq!(status_from_proto(status_to_proto(s.clone())).unwrap(), s);
        }
    }

    #[test]
    fn a_hostile_status_is_bounded_or_refused() {
        let mut m = status_to_proto(status(JobState::Running));
        m.warnings = vec!["x".repeat(10_000); 1000];
        m.samples_per_s = f64::NAN;
        let s = status_from_proto(m.clone()).unwrap();
        assert_eq!(s.warnings.len(), MAX_WARNINGS);
        assert!(s.warnings.iter().all(|w| w.len() == MAX_WARNING_CHARS));
        assert_eq!(s.samples_per_s, 0.0);
        m.state = 99;
        assert!(status_from_proto(m).unwrap_err().contains("unknown state 99"));
    }
}
