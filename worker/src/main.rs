//! The `worker` executable for farm machines; the same worker runs inside `coordinator`
//! (its hidden `worker` subcommand) for `render`'s local workers.

use clap::Parser;

fn main() {
    worker::run(worker::Args::parse())
}
