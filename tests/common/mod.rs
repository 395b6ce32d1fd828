//! Helpers shared by the integration tests. Data comes from the repository's `data/`.
#![allow(dead_code)]

use std::path::PathBuf;

pub fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("data/cmu")
        .join(name)
}

pub fn read(name: &str) -> String {
    std::fs::read_to_string(data(name)).expect("bundled data file")
}

pub fn bin() -> std::process::Command {
    std::process::Command::new(env!("CARGO_BIN_EXE_marionette"))
}

/// Runs `marionette` from the repository with no standard input and waits for it.
pub fn run(args: &[&str]) -> std::process::Output {
    bin()
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdin(std::process::Stdio::null())
        .output()
        .unwrap()
}

/// A fresh directory under the system's temporary directory, one per test process, `name` and
/// thread.
pub fn tempdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!(
        "marionette-{name}-{}-{:?}",
        std::process::id(),
        std::thread::current().id()
    ));
    std::fs::create_dir_all(&d).unwrap();
    d
}
