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

/// Fails the test with one line when `python3` cannot import `module` (the PyPI package `pip`):
/// `scripts/test` installs it, and every other tool the tests need, then runs them all.
pub fn needs_python(module: &str, pip: &str) {
    let ok = std::process::Command::new("python3")
        .args(["-c", &format!("import {module}")])
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    assert!(
        ok,
        "this test needs {pip} for python3: run scripts/test, which installs it"
    );
}

/// Fails the test with one line when `program` is not on the PATH (Debian's `package`).
pub fn needs_program(program: &str, package: &str) {
    let found = std::env::var_os("PATH")
        .is_some_and(|p| std::env::split_paths(&p).any(|d| d.join(program).is_file()));
    assert!(
        found,
        "this test needs {program} (Debian: {package}): run scripts/test, which installs it"
    );
}
