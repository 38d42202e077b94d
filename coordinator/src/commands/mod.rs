//! The commands of the `coordinator` executable, each in its own module; `follow`,
//! `progress`, `local` and `builtin` are what several of them share.

pub mod bench;
pub(crate) mod builtin;
pub mod certs;
pub mod client;
pub(crate) mod follow;
pub(crate) mod frames;
pub mod identities;
pub(crate) mod in_process;
pub mod job_args;
pub mod loadtest;
pub(crate) mod local;
pub(crate) mod progress;
pub mod render;
pub mod serve;
pub(crate) mod spp_map;
