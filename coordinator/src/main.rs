//! `coordinator`: tilefarm's command line — render locally, serve a farm, submit jobs to
//! it, inspect it, and benchmark the tracer.

use coordinator::commands::{bench, certs, client, identities, loadtest, render, serve};

use std::io::Write;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "coordinator", version, about = "tilefarm: a Monte Carlo render farm", long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene on this machine with local worker processes and write an EXR (or a
    /// PNG preview). Without a scene, renders the built-in Cornell box.
    Render(render::RenderArgs),
    /// Continue a render from its checkpoint folder (no scene path needed).
    Resume(render::ResumeArgs),
    /// Run a long-lived farm that workers join and users submit jobs to.
    Serve(serve::ServeArgs),
    /// Upload a scene to a farm and start a job (--wait to follow it and get the image).
    Submit(client::SubmitArgs),
    /// Follow a submitted job to its end and write its image.
    Fetch(client::FetchArgs),
    /// List a farm's jobs and workers.
    Status(client::StatusArgs),
    /// Change a job: its priority, pause or resume it, or render more samples.
    Update(client::UpdateArgs),
    /// Cancel a job.
    Cancel(client::CancelArgs),
    /// List a farm's workers and, for an admin, the identities they registered as, with
    /// their records and bans.
    Workers(identities::WorkersArgs),
    /// Lift the ban on a worker identity (admins only); it is checked afresh as a new one.
    Unban(identities::UnbanArgs),
    /// Make a farm's CA, certificates and access tokens (`certs init DIR`).
    Certs(certs::CertsArgs),
    /// Measure BVH build time, ray throughput and render speed.
    Bench(bench::BenchArgs),
    /// Measure how many unit results a coordinator merges per second: a `serve` child
    /// and many simulated workers on loopback that return tiny units at once.
    Loadtest(loadtest::LoadtestArgs),
    /// Run a worker (the same as the `worker` executable). `render` starts its local
    /// workers this way, so it needs no other binary.
    #[command(hide = true)]
    Worker(worker::Args),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    // A farm logs its jobs and workers; one-shot commands only warn (RUST_LOG overrides).
    match &cli.command {
        Command::Worker(_) => {} // logs as the worker executable does
        Command::Serve(_) => worker::init_logging("info"),
        _ => worker::init_plain_logging("warn"),
    }
    let result = match cli.command {
        Command::Worker(args) => worker::run(args),
        Command::Render(args) => render::run(args),
        Command::Resume(args) => render::resume(args),
        Command::Serve(args) => serve::run(args),
        Command::Submit(args) => client::submit(args),
        Command::Fetch(args) => client::fetch(args),
        Command::Status(args) => client::status(args),
        Command::Update(args) => client::update(args),
        Command::Cancel(args) => client::cancel(args),
        Command::Workers(args) => identities::workers(args),
        Command::Unban(args) => identities::unban(args),
        Command::Certs(args) => certs::run(args),
        Command::Bench(args) => bench::run(args),
        Command::Loadtest(args) => loadtest::run(args),
    };
    let _ = std::io::stdout().flush();
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            let interrupted = e.to_string().starts_with("interrupted");
            std::process::ExitCode::from(if interrupted { 130 } else { 1 })
        }
    }
}
