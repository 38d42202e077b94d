//! The farm's names for workers and units (a job's unit index), shared by the modules
//! below the job so that none of them needs another for a name.

pub type WorkerId = u64;
pub type UnitId = u64;
