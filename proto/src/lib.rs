//! The wire types and services of tilefarm, generated from `tilefarm.proto`, and
//! ([`wire`]) the one checked mapping between them and the domain types that the
//! coordinator and the worker share.

tonic::include_proto!("tilefarm.v1");

pub mod auth;
pub mod domain;
pub mod tls;
pub mod wire;

/// Protocol version: a worker and a coordinator with different versions refuse each
/// other at registration rather than exchanging misunderstood messages.
pub const PROTOCOL_VERSION: u32 = 2;

/// Most results one `SubmitResults` call may carry.
pub const MAX_RESULTS_PER_CALL: usize = 256;

/// Largest message either side accepts. A unit's result is 52 bytes per pixel, so this
/// admits tiles up to ~1000×1000; asset bytes travel in chunks well below it.
pub const MAX_MESSAGE_BYTES: usize = 64 * 1024 * 1024;

/// Size of one asset chunk on the wire.
pub const ASSET_CHUNK_BYTES: usize = 1024 * 1024;

/// The coordinator's address as users give it — `host:port` or a URL — as the URL a
/// channel connects to (`http://` is assumed when no scheme is given). Both sides map
/// the address here, so `worker`, `submit`, `fetch`, `status` and `cancel` accept the
/// same forms.
pub fn coordinator_url(address: &str) -> String {
    let a = address.trim();
    if a.contains("://") { a.to_string() } else { format!("http://{a}") }
}

#[cfg(test)]
mod tests {
    #[test]
    fn addresses_without_a_scheme_get_http() {
        assert_eq!(super::coordinator_url("10.0.0.5:7878"), "http://10.0.0.5:7878");
        assert_eq!(super::coordinator_url(" http://h:1 "), "http://h:1");
        assert_eq!(super::coordinator_url("https://h:1"), "https://h:1");
    }
}
