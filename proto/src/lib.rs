//! The wire types and services of tilefarm, generated from `tilefarm.proto`. Nothing
//! else lives here: conversions to the coordinator's and worker's own types happen at
//! their service edges.

tonic::include_proto!("tilefarm.v1");

/// Protocol version: a worker and a coordinator with different versions refuse each
/// other at registration rather than exchanging misunderstood messages.
pub const PROTOCOL_VERSION: u32 = 1;

/// Largest message either side accepts. A unit's result is 52 bytes per pixel, so this
/// admits tiles up to ~1000×1000; asset bytes travel in chunks well below it.
pub const MAX_MESSAGE_BYTES: usize = 64 * 1024 * 1024;

/// Size of one asset chunk on the wire.
pub const ASSET_CHUNK_BYTES: usize = 1024 * 1024;
