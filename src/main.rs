//! The `marionette` command: see `marionette --help`. Exit codes: 0 success, 1 a runtime
//! error, 2 a usage error.

use clap::Parser;
use std::io::Write;
use std::process::ExitCode;

/// Counts allocations per thread: the control loop reads the count before and after each tick
/// and reports the difference as `allocations_in_tick`.
#[global_allocator]
static GLOBAL: marionette::alloc_count::Counting = marionette::alloc_count::Counting;

fn main() -> ExitCode {
    let cli = marionette::cli::Cli::parse();
    match marionette::cli::run_with(cli, Some(marionette::alloc_count::allocations)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            let msg = e.to_string().replace('\n', " ");
            // After a hang-up stderr may be gone; the exit code still tells.
            let _ = writeln!(std::io::stderr(), "marionette: error: {msg}");
            ExitCode::from(e.exit_code())
        }
    }
}
