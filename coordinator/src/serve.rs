//! `coordinator serve`: a long-running farm.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::Context;
use clap::Args;

use crate::assets::AssetStore;
use crate::farm::{Farm, FarmConfig};
use crate::server::Server;
use crate::service::{JobDefaults, Shared};

#[derive(Args)]
pub struct ServeArgs {
    /// Address to listen on. Loopback unless told otherwise; port 0 picks a free port
    /// (the address is printed).
    #[arg(long, default_value = "127.0.0.1:7878")]
    pub listen: String,
    /// Where uploaded scene files are kept (content-addressed).
    #[arg(long)]
    pub store: Option<PathBuf>,
    /// A lease lapses this many milliseconds after its last renewal; its unit then goes
    /// back to the queue.
    #[arg(long, default_value_t = 30_000)]
    pub lease_ms: u64,
    /// How often workers renew their leases, in milliseconds.
    #[arg(long, default_value_t = 5_000)]
    pub heartbeat_ms: u64,
}

pub fn run(args: ServeArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.heartbeat_ms > 0 && args.lease_ms > args.heartbeat_ms,
        "--lease-ms must exceed --heartbeat-ms"
    );
    let store_dir = args.store.clone().unwrap_or_else(|| std::env::temp_dir().join("tilefarm-coordinator-store"));
    let store = AssetStore::open(&store_dir)?;
    let shared = Arc::new(Shared {
        farm: Mutex::new(Farm::new(FarmConfig {
            lease: Duration::from_millis(args.lease_ms),
            heartbeat: Duration::from_millis(args.heartbeat_ms),
        })),
        store: Mutex::new(store),
        defaults: JobDefaults::default(),
    });
    let runtime =
        tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().context("async runtime")?;
    runtime.block_on(async move {
        let server = Server::start(shared, &args.listen).await?;
        // The first line of output is the URL, for scripts and tests.
        println!("listening on {}", server.url());
        tracing::info!(store = %store_dir.display(), "coordinator serving");
        let _ = crate::stop_signal().await;
        tracing::info!("stopping");
        server.stop().await;
        Ok(())
    })
}
