//! The farm's state: jobs ([`job`]) and their units ([`unit`]), lease deadlines ([`leases`]),
//! workers ([`workers`]) and the identities they are trusted and banned as ([`identities`]),
//! users' and the farm's budgets ([`budgets`]), the coordinator's own render of what no
//! identity can settle ([`arbiter`]),
//! the unit order ([`schedule`]), job groups' frame order ([`groups`]), registered workers and the jobs in submission order
//! ([`state`]), checkpoints ([`checkpoint`]), the content-addressed asset store
//! ([`assets`]), what a job's status says ([`status`]), what lies beside a stored image ([`stored`]), and the job lifecycle
//! ([`lifecycle`]) that ties them together, and what it counts for metrics ([`meters`]). No wire types: the edge maps them.

pub mod arbiter;
pub mod assets;
pub mod budgets;
pub mod checkpoint;
pub mod groups;
pub mod identities;
pub mod ids;
pub mod job;
pub mod leases;
pub mod lifecycle;
pub mod meters;
pub mod schedule;
pub mod state;
pub mod status;
pub mod stored;
pub mod unit;
pub mod verify;
pub mod workers;

pub use lifecycle::Shared;
pub use state::{Farm, FarmConfig, FarmError};
