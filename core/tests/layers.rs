//! The core's modules are layers: `lib.rs` lists them from the bottom up, and each module may
//! use only the modules listed before it (never itself through `crate::`, never one above).

use std::path::Path;

fn source(name: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("src").join(name);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The modules in `lib.rs` order.
fn layers() -> Vec<String> {
    source("lib.rs")
        .lines()
        .filter_map(|l| l.strip_prefix("pub mod "))
        .map(|l| l.trim_end_matches(';').to_string())
        .collect()
}

/// The modules a file names as `crate::NAME` (code and doc links alike).
fn uses(text: &str, modules: &[String]) -> Vec<String> {
    modules
        .iter()
        .filter(|m| {
            let needle = format!("crate::{m}");
            text.match_indices(&needle).any(|(i, _)| {
                let next = text[i + needle.len()..].chars().next();
                !next.is_some_and(|c| c.is_alphanumeric() || c == '_')
            })
        })
        .cloned()
        .collect()
}

#[test]
fn every_module_uses_only_modules_below_it() {
    let modules = layers();
    assert!(modules.len() >= 13, "{modules:?}");
    let mut wrong = Vec::new();
    for (k, m) in modules.iter().enumerate() {
        let text = source(&format!("{m}.rs"));
        for used in uses(&text, &modules) {
            let at = modules.iter().position(|x| *x == used).unwrap();
            if at >= k {
                wrong.push(format!("{m} uses {used}"));
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "layer order broken: {wrong:?} (order: {modules:?})"
    );
}

#[test]
fn the_checker_sees_a_use_from_above() {
    let modules = layers();
    assert_eq!(uses("use crate::servo::{addr, MAX_SERVOS};", &modules), ["servo"]);
    assert_eq!(uses("crate::skeleton_extra", &modules), Vec::<String>::new());
}
