//! The `marionette` command: see `marionette --help`.

use clap::Parser;
use std::process::ExitCode;

fn main() -> ExitCode {
    let cli = marionette::cli::Cli::parse();
    match marionette::cli::run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            let msg = e.to_string().replace('\n', " ");
            eprintln!("marionette: error: {msg}");
            ExitCode::FAILURE
        }
    }
}
