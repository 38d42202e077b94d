//! Job groups: an animation's frames, submitted together under one name. A group's
//! frames start in submission order, a few at a time ([`due_frames`]), so that the
//! coordinator holds a few images, not the whole shot's; and they take units one frame
//! after another ([`first_frames`]), so that no frame's tiles wait for a later frame and
//! the next frame takes the workers as soon as the one before has nothing left to give.
//! Between a group and other jobs, the fair share (`schedule`) is unchanged.

use std::collections::{HashMap, HashSet};

use super::job::{Job, JobPhase};

/// Most frames of one job group loading or running at once.
pub const FRAMES_IN_FLIGHT: usize = 3;

/// A job group: its owner's, by name (two users' groups of one name are two groups).
type GroupKey = (Option<String>, String);

fn group_key(j: &Job) -> Option<GroupKey> {
    Some((j.owner.clone(), j.group.clone()?))
}

/// The queued frames among `jobs` (in submission order) that may start now, marked as
/// loading: in order, until [`FRAMES_IN_FLIGHT`] of their group are loading or running.
pub fn due_frames<'a>(jobs: impl Iterator<Item = &'a mut Job>) -> Vec<String> {
    let jobs: Vec<&mut Job> = jobs.collect();
    let mut in_flight: HashMap<GroupKey, usize> = HashMap::new();
    for j in &jobs {
        if let (Some(g), JobPhase::Loading | JobPhase::Running) = (group_key(j), &j.phase) {
            *in_flight.entry(g).or_default() += 1;
        }
    }
    let mut due = Vec::new();
    for j in jobs {
        let Some(g) = group_key(j) else { continue };
        if j.phase != JobPhase::Queued {
            continue;
        }
        let n = in_flight.entry(g).or_default();
        if *n < FRAMES_IN_FLIGHT {
            *n += 1;
            j.phase = JobPhase::Loading;
            due.push(j.id.clone());
        } else {
            // Later frames wait behind this one.
            *n = usize::MAX;
        }
    }
    due
}

/// Of `jobs` (in submission order) with whether each could take a unit, those that may:
/// every job alone, and of each group only its first such frame.
pub fn first_frames<'a>(jobs: impl Iterator<Item = (&'a Job, bool)>) -> Vec<bool> {
    let mut served: HashSet<GroupKey> = HashSet::new();
    jobs.map(|(j, could)| could && group_key(j).is_none_or(|g| served.insert(g))).collect()
}

#[cfg(test)]
mod tests {
    use std::time::Instant;

    use proto::domain::JobSpec;

    use super::*;
    use crate::farm::state::{Farm, FarmConfig};

    /// A job group's frames start in order, at most `FRAMES_IN_FLIGHT` at once, and take
    /// units one frame after another; other jobs (and another user's group of the same
    /// name) keep their fair share beside them.
    #[test]
    fn a_groups_frames_start_and_render_in_order_a_few_at_a_time() {
        let mut f = Farm::new(FarmConfig::default());
        let now = Instant::now();
        let w = f.register("h".into(), 4, now); // holds up to 32 units
        let frame = |group: &str| JobSpec { group: Some(group.into()), ..super::super::state::tests::spec() };
        let alone = f.add_job("alone".into(), None, super::super::state::tests::spec());
        let frames: Vec<String> = (1..=5).map(|i| f.add_job(format!("shot.{i:04}"), None, frame("shot"))).collect();
        let bobs = f.add_job("shot.0001".into(), Some("bob".into()), frame("shot"));
        assert!(frames.iter().all(|id| f.entry(id).unwrap().job.phase == JobPhase::Queued));
        assert_eq!(f.entry(&alone).unwrap().job.phase, JobPhase::Loading, "a job alone loads at once");
        let due = f.due_frames();
        assert_eq!(due, [&frames[..FRAMES_IN_FLIGHT], std::slice::from_ref(&bobs)].concat());
        assert!(f.due_frames().is_empty(), "three of the group in flight");
        // 4 tiles × 2 batches: 8 units a frame.
        for id in due.iter().chain([&alone]) {
            f.entry_mut(id).unwrap().job.start(16, 16, 4, 8, 2, true);
        }
        let order: Vec<String> = f.lease(w, 30, now).unwrap().into_iter().map(|l| l.spec.job_id.clone()).collect();
        let ours: Vec<usize> = order.iter().filter_map(|id| frames.iter().position(|f| f == id)).collect();
        assert_eq!(ours, [vec![0; 8], vec![1; 6]].concat(), "frame 1's units all before frame 2's: {order:?}");
        let count = |id: &String| order.iter().filter(|o| *o == id).count();
        assert_eq!((count(&alone), count(&bobs)), (8, 8), "the others' shares, beside the group's: {order:?}");
        // A frame ends: the next queued one starts.
        f.entry_mut(&frames[0]).unwrap().job.cancel();
        assert_eq!(f.due_frames(), [frames[3].clone()]);
    }
}
