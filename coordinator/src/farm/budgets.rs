//! Budgets: how many jobs a user may have at once, and how much memory a user's jobs
//! and all jobs may hold while they run (see [`Job::memory`](super::job::Job::memory)).

use super::job::JobPhase;
use super::state::{Farm, FarmError, JobEntry};

impl Farm {
    /// Whether `owner` may submit one more job ([`FarmConfig::max_user_jobs`]); admins
    /// (no owner) may.
    pub fn may_submit(&self, owner: Option<&str>) -> Result<(), FarmError> {
        let Some(user) = owner else { return Ok(()) };
        let most = self.config.max_user_jobs;
        let live = self.jobs.iter().filter(|e| e.job.owner.as_deref() == Some(user) && !e.job.phase.is_final()).count();
        if live >= most {
            return Err(FarmError::Exhausted(format!(
                "{user} already has {live} jobs loading, queued or running, the most a user may have \
                 (--max-user-jobs {most}); wait for one to finish, or cancel one"
            )));
        }
        Ok(())
    }

    /// Reserves `bytes` for `job` as it starts, within its user's budget and the farm's;
    /// the error names the limit. Jobs loading, queued or running count, and finished
    /// ones until their image is stored and their sums leave memory.
    pub fn reserve(&mut self, job: &str, bytes: u64) -> Result<(), String> {
        let owner = self.entry(job).map_err(|e| e.to_string())?.job.owner.clone();
        let held = |same: &dyn Fn(&JobEntry) -> bool| -> u64 {
            let holds = |e: &JobEntry| match e.job.phase {
                JobPhase::Done => !e.job.is_evicted(),
                ref p => !p.is_final(),
            };
            self.jobs.iter().filter(|e| e.job.id != job && holds(e) && same(e)).map(|e| e.bytes).sum()
        };
        let mib = |b: u64| b.div_ceil(1 << 20);
        if let Some(user) = &owner {
            let mine = held(&|e| e.job.owner.as_ref() == Some(user));
            let most = self.config.max_user_bytes;
            if mine + bytes > most {
                return Err(format!(
                    "this job needs {} MiB, and {user}'s other jobs hold {} MiB: more than a user's limit of {} MiB \
                     (--max-user-memory-mb); wait for one to finish, or cancel one",
                    mib(bytes),
                    mib(mine),
                    mib(most)
                ));
            }
        }
        let all = held(&|_| true);
        let most = self.config.max_farm_bytes;
        if all + bytes > most {
            return Err(format!(
                "this job needs {} MiB, and the farm's running jobs hold {} MiB: more than its limit of {} MiB \
                 (--max-farm-memory-mb); submit it again when others have finished",
                mib(bytes),
                mib(all),
                mib(most)
            ));
        }
        self.entry_mut(job).map_err(|e| e.to_string())?.bytes = bytes;
        Ok(())
    }
}
