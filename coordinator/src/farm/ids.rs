//! The farm's names for workers, identities and units (a job's unit index), shared by
//! the modules below the job so that none of them needs another for a name.

pub type WorkerId = u64;
pub type UnitId = u64;
/// An identity the farm trusts or bans as one: a worker certificate, or a token's
/// caller (on a farm without access control, each registration is its own). Checks
/// settle only between different identities.
pub type IdentityId = u64;

/// Who returned a result or asks for work: a registration, and the identity it belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct By {
    pub worker: WorkerId,
    pub identity: IdentityId,
}

impl From<WorkerId> for By {
    /// A worker that is its own identity (the job's tests, and farms without access
    /// control).
    fn from(worker: WorkerId) -> Self {
        Self { worker, identity: worker }
    }
}
