//! `dvnav`: train, run and inspect dimension-variable mapless navigation agents.
//!
//! Each subcommand is a thin layer over the library crates: `train` supervises a learner and N
//! actor processes on this machine; `learner` and `actor` are those two roles on their own, for
//! runs across machines; `eval` evaluates a checkpoint (rooms, routes, the gate and dynamic
//! scenarios); `inspect` reads MCAP episode logs and `plot` draws them ([`render`]).

mod cli;
/// The figures: [`dvnav_render`], known here as `render`.
use dvnav_render as render;

use clap::Parser;

/// Counts the bytes in use, so `/metrics` and the soak test can tell a leak from the allocator's
/// high-water mark ([`dvnav_learner::alloc_count`]).
#[global_allocator]
static ALLOCATOR: dvnav_learner::alloc_count::CountingAllocator =
    dvnav_learner::alloc_count::CountingAllocator;

/// Keeps freed tensor buffers in the heap instead of returning them to the kernel.
///
/// candle allocates and frees multi-megabyte buffers for every op of every update. glibc's
/// default serves allocations above 128 KiB with fresh `mmap`s and unmaps them on free, so
/// every op paid for page faults and kernel page zeroing: ~25 % of a SAC update's time in a
/// profile (`perf record dvnav bench learner`). Raising the thresholds makes freed buffers
/// reusable.
fn tune_allocator() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes allocator parameters; called before any other thread runs.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 256 * 1024 * 1024);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 512 * 1024 * 1024);
    }
}

/// Dies quietly on a closed pipe (`dvnav inspect … | head`), like other command-line tools,
/// instead of panicking in `println!`: Rust ignores SIGPIPE by default. Only for the commands
/// that hold no network socket ([`cli::Cli::prints_only`]): with the default disposition, a
/// write to a connection the peer has reset kills the process (the multi-host test's learner
/// died so when a cut link came back).
fn restore_sigpipe() {
    #[cfg(unix)]
    // SAFETY: resets one signal disposition before any other thread exists (argument parsing
    // starts none).
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

fn main() -> std::process::ExitCode {
    tune_allocator();
    let args = cli::Cli::parse();
    if args.prints_only() {
        restore_sigpipe();
    }
    cli::init_tracing(args.verbose);
    match cli::dispatch(args) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
