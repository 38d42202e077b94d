//! The gRPC edge: the services a farm offers ([`service`]), the server that runs them
//! ([`server`]), and the mapping of the coordinator's own messages ([`wire`]; the
//! messages shared with workers are mapped in `proto::wire`).

pub mod client;
pub mod in_process;
pub mod server;
pub mod service;
pub mod wire;
