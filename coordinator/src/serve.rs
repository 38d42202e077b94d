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
    #[command(flatten)]
    pub farm: FarmArgs,
}

/// How the farm treats leases; shared by `serve` and `render`.
#[derive(Args, Clone, Debug)]
pub struct FarmArgs {
    /// A lease lapses this many milliseconds after its last renewal; its unit then goes
    /// back to the queue (this bounds how long a dead worker's units wait).
    #[arg(long, default_value_t = 30_000)]
    pub lease_ms: u64,
    /// How often workers renew their leases, in milliseconds.
    #[arg(long, default_value_t = 5_000)]
    pub heartbeat_ms: u64,
    /// When no unit is left in the queue, a unit out with one worker for this many
    /// milliseconds is also given to an idle worker; the first result wins.
    #[arg(long, default_value_t = 10_000)]
    pub speculate_after_ms: u64,
}

impl FarmArgs {
    pub fn config(&self) -> anyhow::Result<FarmConfig> {
        anyhow::ensure!(
            self.heartbeat_ms > 0 && self.lease_ms > self.heartbeat_ms,
            "--lease-ms must exceed --heartbeat-ms"
        );
        Ok(FarmConfig {
            lease: Duration::from_millis(self.lease_ms),
            heartbeat: Duration::from_millis(self.heartbeat_ms),
            speculate_after: Duration::from_millis(self.speculate_after_ms),
        })
    }
}

pub fn run(args: ServeArgs) -> anyhow::Result<()> {
    let config = args.farm.config()?;
    let store_dir = args.store.clone().unwrap_or_else(|| std::env::temp_dir().join("tilefarm-coordinator-store"));
    let store = AssetStore::open(&store_dir)?;
    let shared = Arc::new(Shared {
        farm: Mutex::new(Farm::new(config)),
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
