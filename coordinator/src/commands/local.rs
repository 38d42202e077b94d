//! Spawning and reaping local worker processes. Each gets a pipe as its standard input
//! and runs with `--exit-on-stdin-eof`, so that it exits when this process does — even
//! when this process is killed and has no chance to clean up.

use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::Duration;

use anyhow::Context;
use tokio::process::{Child, Command};

pub struct LocalWorkers {
    children: Vec<Child>,
}

/// This executable, which runs a worker as `coordinator worker …`: a local render needs
/// no second binary (a fresh `cargo run -p coordinator -- render` builds only this one).
fn worker_executable() -> anyhow::Result<PathBuf> {
    std::env::current_exe().context("locating this executable")
}

impl LocalWorkers {
    /// `token` reaches them in their environment (not on their command line, which any
    /// user of the machine can read).
    pub fn spawn(
        count: usize,
        threads: usize,
        url: &str,
        cache_root: &Path,
        scene_cache: Option<&Path>,
        token: &proto::auth::Token,
    ) -> anyhow::Result<Self> {
        let exe = worker_executable()?;
        let mut children = Vec::with_capacity(count);
        for i in 0..count {
            let mut cmd = Command::new(&exe);
            // Quiet by default: the progress bar is this process's to draw.
            if std::env::var_os("RUST_LOG").is_none() {
                cmd.env("RUST_LOG", "warn");
            }
            cmd.env(proto::auth::TOKEN_ENV, token.secret());
            let child = cmd
                .arg("worker")
                .arg("--coordinator")
                .arg(url)
                .arg("--threads")
                .arg(threads.to_string())
                .arg("--cache")
                .arg(cache_root.join(format!("worker-{i}")))
                .args(match scene_cache {
                    Some(dir) => vec!["--scene-cache".into(), dir.as_os_str().to_owned()],
                    None => vec!["--scene-cache-max-mb".into(), "0".into()],
                })
                .arg("--exit-on-stdin-eof")
                .arg("--trust-scene-paths")
                .stdin(Stdio::piped())
                .kill_on_drop(true)
                .spawn()
                .with_context(|| format!("starting {}", exe.display()))?;
            children.push(child);
        }
        Ok(Self { children })
    }

    /// How many are still running.
    pub fn running(&mut self) -> usize {
        self.children.iter_mut().map(|c| c.try_wait()).filter(|s| matches!(s, Ok(None))).count()
    }

    /// Waits up to `grace` for the workers to exit on their own, then kills the rest.
    pub async fn shutdown(mut self, grace: Duration) {
        let deadline = tokio::time::Instant::now() + grace;
        for c in &mut self.children {
            if tokio::time::timeout_at(deadline, c.wait()).await.is_err() {
                let _ = c.kill().await;
            }
        }
    }

    pub async fn kill(mut self) {
        for c in &mut self.children {
            let _ = c.kill().await;
        }
    }
}
