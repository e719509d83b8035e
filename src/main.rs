//! `dvnav`: train, run and inspect dimension-variable mapless navigation agents.
//!
//! Each subcommand is a thin layer over the library crates: `train` supervises a learner and N
//! actor processes on this machine; `learner` and `actor` are those two roles on their own, for
//! runs across machines; `inspect` reads MCAP episode logs.

mod cli;

use clap::Parser;

fn main() -> std::process::ExitCode {
    let args = cli::Cli::parse();
    cli::init_tracing(args.verbose);
    match cli::dispatch(args) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
