//! `coordinator`: tilefarm's command line. `render` renders a scene in this process;
//! `bench` prints traversal and rendering figures.

mod bench;
mod builtin;
mod render_cmd;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "coordinator", version, about = "tilefarm: a Monte Carlo render farm", long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene in this process (all cores) and write an EXR (or a PNG preview).
    Render(render_cmd::RenderArgs),
    /// Measure kd-tree build time, ray throughput and render speed.
    Bench(bench::BenchArgs),
}

fn main() -> std::process::ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Render(args) => render_cmd::run(args),
        Command::Bench(args) => bench::run(args),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
