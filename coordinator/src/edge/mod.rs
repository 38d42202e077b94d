//! The edge: the gRPC services a farm offers ([`service`]), the server that runs them
//! ([`server`]), its HTTP side for metrics, health ([`http`]) and the live dashboard ([`dashboard`]), and the mapping of the
//! coordinator's own messages ([`wire`]; the messages shared with workers are mapped in
//! `proto::wire`), and what both servers' listeners admit ([`conn`]).

mod app;
pub mod client;
pub mod conn;
mod dashboard;
pub mod http;
pub mod in_process;
pub mod server;
pub mod service;
pub mod wire;
