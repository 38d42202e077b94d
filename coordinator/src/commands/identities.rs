//! `coordinator workers` and `coordinator unban`: an admin's view of who works for the
//! farm (its workers, and the identities they registered as, with their records and
//! bans), and lifting a ban.

use clap::Args;

use super::client::{FarmAddress, runtime};

#[derive(Args)]
pub struct WorkersArgs {
    #[command(flatten)]
    pub coordinator: FarmAddress,
}

#[derive(Args)]
pub struct UnbanArgs {
    /// The banned identity, as `coordinator workers` lists it (a worker certificate's
    /// `cert:` fingerprint, or a token's user name).
    pub identity: String,
    #[command(flatten)]
    pub coordinator: FarmAddress,
}

pub fn workers(args: WorkersArgs) -> anyhow::Result<()> {
    runtime()?.block_on(async move {
        let mut client = args.coordinator.connect().await?;
        let workers = client.workers().await?;
        let identities = client.identities().await?;
        let mut out = String::from("workers:\n");
        if workers.is_empty() {
            out.push_str("  (none)\n");
        }
        for w in &workers {
            let state = if w.quarantined { "  QUARANTINED (its identity is banned)" } else { "" };
            out.push_str(&format!(
                "  {:<16} {:<20} {:<22} {:>3} threads  {:>6} done  seen {:.1}s ago{state}\n",
                w.id, w.hostname, w.identity, w.threads, w.units_done, w.last_seen_s
            ));
        }
        out.push_str("identities:\n");
        if identities.is_empty() {
            out.push_str("  (none, or you are not an admin)\n");
        }
        for i in &identities {
            out.push_str(&format!(
                "  {:<22} {:>3} workers  {:>7} results taken  {:>3} refused",
                i.name, i.workers, i.answers, i.refused
            ));
            if let Some((reason, at)) = &i.ban {
                out.push_str(&format!("  BANNED {} ({reason}); lift: coordinator unban {}", ago(*at), i.name));
            }
            out.push('\n');
        }
        print!("{out}");
        Ok(())
    })
}

pub fn unban(args: UnbanArgs) -> anyhow::Result<()> {
    runtime()?.block_on(async move {
        let mut client = args.coordinator.connect().await?;
        let reason = client.unban(&args.identity).await?;
        println!("{}: ban lifted (it had {reason}); its record starts afresh", args.identity);
        Ok(())
    })
}

/// How long ago `at` (seconds since 1970) was, for people.
fn ago(at: u64) -> String {
    let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs());
    let s = now.saturating_sub(at);
    match s {
        0..120 => format!("{s} s ago"),
        120..7200 => format!("{} min ago", s / 60),
        _ => format!("{} h ago", s / 3600),
    }
}
