//! tilefarm's worker: registers with a coordinator, leases units of work (a tile × a
//! range of samples of a job), renders them on all cores, and sends the results back.
//!
//! - this file: the command line ([`Args`], [`run`]), logging, signals and standard input.
//!   It is a library so that `coordinator render` can start its local workers from its
//!   own executable (`coordinator worker …`): a fresh `cargo run -p coordinator` then
//!   needs no separately built `worker` binary.
//! - [`machine`]: the register/lease/heartbeat/submit state machine: events in,
//!   actions out, no I/O (unit-tested without a network or a clock).
//! - [`shell`]: performs the machine's actions (calls, scene loads, renders) and
//!   reports their outcomes back to it ([`drive`]).
//! - [`link`] and [`executor`]: the seams the shell performs them through — a
//!   coordinator (over gRPC here; in process for `render --local-workers 0`) and a place
//!   to render (the render pool; the load test's empty results).
//! - [`asset_cache`]: scene files by digest, job folders, loaded scenes.
//! - [`render_pool`]: the render threads.
//! - `proto::wire`: checked conversions between wire messages and the worker's types.
//! - [`rpc`]: the client, call timeouts, failure classes.

mod asset_cache;
mod executor;
mod failure;
mod link;
mod machine;
mod render_pool;
mod rpc;
mod shell;

pub use asset_cache::LoadedJob;
pub use executor::{Executor, RenderOutcome};
pub use link::{GrpcLink, Link};
pub use machine::{Failure, Grant, Registration, Rendered, Renewal, Settings};
pub use render_pool::RenderPool;
pub use rpc::Credentials;
pub use shell::{Stop, drive};

use std::io::Read;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use clap::Parser;
use tokio::sync::watch;
use tracing::{error, info, warn};

/// tilefarm worker: leases units of rendering work from a coordinator, renders them on
/// all cores, and streams the results back.
#[derive(Parser, Debug)]
#[command(name = "worker", version, about, long_about = None)]
pub struct Args {
    /// Address of the coordinator's gRPC endpoint, e.g. http://10.0.0.5:7878
    /// (http:// is assumed when no scheme is given). The worker waits for it, retrying
    /// with backoff, if it is not up yet.
    #[arg(long, value_name = "URL")]
    coordinator: String,

    /// Render threads [default: all cores]. Up to twice this many units are kept
    /// leased, so no core waits between units.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=4096))]
    threads: Option<u32>,

    /// Cache folder for scene files (stored by SHA-256) and job folders
    /// [default: tilefarm-worker-cache in the system temp folder].
    #[arg(long, value_name = "DIR")]
    cache: Option<PathBuf>,

    /// Folder where loaded scenes are kept prepared (mesh and BVH), so that the next
    /// job of the same scene starts without parsing and building; it must be private to
    /// this user [default: prepared/ in the --cache folder].
    #[arg(long, value_name = "DIR")]
    scene_cache: Option<PathBuf>,

    /// Most megabytes of prepared scenes to keep (the least recently used go first);
    /// 0 keeps none.
    #[arg(long, value_name = "MB", default_value_t = tracer::scene::prepared::DEFAULT_MAX_BYTES >> 20)]
    scene_cache_max_mb: u64,

    /// Also exit when standard input reaches end of file. The coordinator's
    /// `render --local-workers` gives its workers a pipe so that they exit with it.
    #[arg(long)]
    exit_on_stdin_eof: bool,

    /// Longest wait between retries while the coordinator is unreachable (the backoff
    /// starts at 100 ms and doubles up to this).
    #[arg(long, value_name = "MS", default_value_t = 5000, value_parser = clap::value_parser!(u64).range(1..=3_600_000))]
    max_backoff_ms: u64,

    /// Exit (code 0) once the coordinator has been unreachable for this many
    /// milliseconds. By default the worker waits for it forever, retrying with backoff,
    /// so a farm survives a coordinator restart.
    #[arg(long, value_name = "MS")]
    give_up_after_ms: Option<u64>,

    /// Let scenes refer to files outside their job (absolute paths, `..`): what
    /// `coordinator render` gives its own local workers, which read the user's scene where
    /// it lies. A farm's workers never trust a scene's paths.
    #[arg(long, hide = true)]
    trust_scene_paths: bool,

    /// The farm's TLS folder (from `coordinator certs init`, copied to this machine):
    /// connect over TLS, trusting the farm's CA, and prove this worker with its
    /// certificate (`worker.pem` and `worker.key`, or those --tls-name gives).
    #[arg(long, value_name = "DIR", env = "TILEFARM_TLS")]
    tls: Option<PathBuf>,

    /// Which certificate in the --tls folder is this worker's: NAME.pem and NAME.key.
    #[arg(long, value_name = "NAME", default_value = proto::tls::WORKER, requires = "tls")]
    tls_name: String,
}

/// Runs a worker until it is told to stop, then exits the process.
pub fn run(args: Args) -> ! {
    init_logging("info");
    let threads = args
        .threads
        .map(|n| n as usize)
        .unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1));
    let runtime = match tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("worker-io")
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            error!("cannot start the async runtime: {e}");
            std::process::exit(1);
        }
    };
    let cache_dir = args.cache.unwrap_or_else(asset_cache::default_cache_dir);
    let prepared = (args.scene_cache_max_mb > 0).then(|| {
        (
            args.scene_cache.unwrap_or_else(|| cache_dir.join("prepared")),
            args.scene_cache_max_mb.saturating_mul(1 << 20),
        )
    });
    let config = shell::Config {
        coordinator: args.coordinator,
        threads,
        cache_dir,
        prepared,
        max_backoff: Duration::from_millis(args.max_backoff_ms),
        give_up_after: args.give_up_after_ms.map(Duration::from_millis),
        trust_scene_paths: args.trust_scene_paths,
        tls: args.tls,
        tls_name: args.tls_name,
    };
    let code = runtime.block_on(async move {
        let (stop_tx, stop_rx) = watch::channel(None);
        let stop_tx = Arc::new(stop_tx);
        watch_signals(stop_tx.clone());
        if args.exit_on_stdin_eof {
            watch_stdin(stop_tx);
        }
        match shell::run(config, stop_rx).await {
            Ok(()) => 0,
            Err(e) => {
                error!("{e:#}");
                1
            }
        }
    });
    // Render threads may still be busy with units that were dropped on the way out, and
    // a scene may still be loading: exit now rather than wait for them.
    std::process::exit(code)
}

/// Logs to standard error at `default_level` (`RUST_LOG` overrides), with colour codes
/// only on a terminal and never when `NO_COLOR` is set (<https://no-color.org>), so
/// pipes and log files get plain text.
pub fn init_logging(default_level: &str) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_level));
    tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).with_ansi(color_wanted()).init();
}

/// Logging for one-shot commands (`render`, `submit`, ...): a person reads it, so each
/// event is one plain line, `warning: ...` or `error: ...`, without time stamps, module
/// paths or fields (`RUST_LOG` still chooses what is shown).
pub fn init_plain_logging(default_level: &str) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_level));
    tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).event_format(PlainLine).init();
}

struct PlainLine;

impl<S, N> tracing_subscriber::fmt::FormatEvent<S, N> for PlainLine
where
    S: tracing::Subscriber + for<'a> tracing_subscriber::registry::LookupSpan<'a>,
    N: for<'a> tracing_subscriber::fmt::FormatFields<'a> + 'static,
{
    fn format_event(
        &self,
        _: &tracing_subscriber::fmt::FmtContext<'_, S, N>,
        mut writer: tracing_subscriber::fmt::format::Writer<'_>,
        event: &tracing::Event<'_>,
    ) -> std::fmt::Result {
        let level = match *event.metadata().level() {
            tracing::Level::ERROR => "error",
            tracing::Level::WARN => "warning",
            tracing::Level::INFO => "info",
            tracing::Level::DEBUG => "debug",
            tracing::Level::TRACE => "trace",
        };
        let mut message = MessageOnly(String::new());
        event.record(&mut message);
        writeln!(writer, "{level}: {}", message.0)
    }
}

/// Keeps an event's message, dropping its other fields.
struct MessageOnly(String);

impl tracing::field::Visit for MessageOnly {
    fn record_debug(&mut self, field: &tracing::field::Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            self.0 = format!("{value:?}");
        }
    }
}

/// Colour on standard error: a terminal, and `NO_COLOR` unset or empty.
pub fn color_wanted() -> bool {
    let no_color = std::env::var_os("NO_COLOR").is_some_and(|v| !v.is_empty());
    !no_color && std::io::IsTerminal::is_terminal(&std::io::stderr())
}

/// SIGINT/SIGTERM: stop (submitting finished results for up to ~2 s); a second signal
/// exits at once.
fn watch_signals(stop: Arc<watch::Sender<Option<Stop>>>) {
    tokio::spawn(async move {
        #[cfg(unix)]
        let mut term = match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(s) => Some(s),
            Err(e) => {
                warn!("cannot watch SIGTERM: {e}");
                None
            }
        };
        let mut received = 0;
        loop {
            #[cfg(unix)]
            {
                let sigterm = async {
                    match term.as_mut() {
                        Some(t) => t.recv().await,
                        None => std::future::pending().await,
                    }
                };
                tokio::select! {
                    r = tokio::signal::ctrl_c() => if let Err(e) = r {
                        warn!("cannot watch SIGINT: {e}");
                        std::future::pending::<()>().await;
                    },
                    _ = sigterm => {}
                }
            }
            #[cfg(not(unix))]
            if let Err(e) = tokio::signal::ctrl_c().await {
                warn!("cannot watch Ctrl-C: {e}");
                return;
            }
            received += 1;
            if received == 1 {
                let _ = stop.send(Some(Stop::Signal));
            } else {
                info!("second signal: exiting now");
                std::process::exit(0);
            }
        }
    });
}

/// Blocks until standard input reaches end of file (or cannot be read): how a process
/// started with a pipe learns that its parent is gone.
pub fn block_until_stdin_eof() {
    let mut stdin = std::io::stdin().lock();
    let mut buf = [0u8; 4096];
    loop {
        match stdin.read(&mut buf) {
            Ok(0) => return,
            Ok(_) => {}
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(_) => return,
        }
    }
}

/// `--exit-on-stdin-eof`: a plain thread blocks reading standard input (it never
/// delays the runtime's shutdown) and asks the worker to stop at end of file.
fn watch_stdin(stop: Arc<watch::Sender<Option<Stop>>>) {
    let spawned = std::thread::Builder::new().name("stdin-watch".into()).spawn(move || {
        block_until_stdin_eof();
        let _ = stop.send(Some(Stop::StdinEof));
    });
    if let Err(e) = spawned {
        warn!("cannot watch standard input: {e}");
    }
}
