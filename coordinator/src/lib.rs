//! tilefarm's coordinator as a library, in three layers, arrows pointing down:
//! - [`commands`]: what the `coordinator` executable does (render, serve, submit, fetch,
//!   status, cancel, bench, loadtest);
//! - [`edge`]: the gRPC services and the client's calls: decode, act on the state,
//!   encode — nothing else;
//! - [`farm`]: the farm's state (jobs, units, leases, workers, checkpoints, the asset
//!   store) and the job lifecycle, with no wire types in it.

pub mod commands;
pub mod edge;
pub mod farm;

/// Resolves on Ctrl-C (SIGINT) or SIGTERM.
pub async fn stop_signal() {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        match signal(SignalKind::terminate()) {
            Ok(mut term) => {
                tokio::select! {
                    _ = tokio::signal::ctrl_c() => {}
                    _ = term.recv() => {}
                }
            }
            Err(_) => {
                let _ = tokio::signal::ctrl_c().await;
            }
        }
    }
    #[cfg(not(unix))]
    {
        let _ = tokio::signal::ctrl_c().await;
    }
}
