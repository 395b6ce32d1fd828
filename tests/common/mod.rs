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
