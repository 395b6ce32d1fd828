//! The commands in the README, the guides (`docs/*.md`) and BENCHMARKS.md, so the documentation
//! cannot rot: every `marionette` command in a shell block names a command that exists, only
//! options its `--help` lists and files the repository has; the ones in the README and the
//! guides that need no hardware, no network and no terminal are run, from a scratch directory
//! that sees the repository's data, and must exit 0. The rig profile reference lists exactly the
//! keys the profile loader reads.

mod common;

use std::collections::HashMap;
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// A command as the documentation writes it.
struct Documented {
    file: String,
    line: usize,
    text: String,
    /// The arguments after `marionette` (or `cargo run --release [--features F] --`).
    args: Vec<String>,
    /// The features it is built with (`cargo run --features`).
    features: Vec<String>,
}

/// Splits a shell line into words: whitespace outside quotes; quotes removed.
fn words(line: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut word = String::new();
    let mut quote = None;
    let mut any = false;
    for c in line.chars() {
        match (quote, c) {
            (None, '\'' | '"') => {
                quote = Some(c);
                any = true;
            }
            (Some(q), c) if c == q => quote = None,
            (None, c) if c.is_whitespace() => {
                if any {
                    out.push(std::mem::take(&mut word));
                    any = false;
                }
            }
            (_, c) => {
                word.push(c);
                any = true;
            }
        }
    }
    if any {
        out.push(word);
    }
    out
}

/// The line without its trailing `# comment` (a `#` outside quotes after a space).
fn without_comment(line: &str) -> &str {
    let mut quote = None;
    let mut prev = ' ';
    for (i, c) in line.char_indices() {
        match (quote, c) {
            (None, '\'' | '"') => quote = Some(c),
            (Some(q), c) if c == q => quote = None,
            (None, '#') if prev.is_whitespace() => return line[..i].trim_end(),
            _ => {}
        }
        prev = c;
    }
    line.trim_end()
}

/// The `marionette` commands of one Markdown file's shell blocks (continuation lines joined).
fn documented_in(path: &Path) -> Vec<Documented> {
    let text = std::fs::read_to_string(path).unwrap();
    let file = path.strip_prefix(root()).unwrap_or(path).display().to_string();
    let mut out = Vec::new();
    let mut in_shell = false;
    let mut pending: Option<(usize, String)> = None;
    for (k, raw) in text.lines().enumerate() {
        if raw.trim_start().starts_with("```") {
            in_shell = !in_shell && matches!(raw.trim(), "```sh" | "```bash" | "```shell");
            pending = None;
            continue;
        }
        if !in_shell {
            continue;
        }
        let (first, joined) = match pending.take() {
            Some((first, before)) => (first, format!("{before} {}", raw.trim())),
            None => (k + 1, raw.trim().to_string()),
        };
        let line = without_comment(&joined).to_string();
        if let Some(stripped) = line.strip_suffix('\\') {
            pending = Some((first, stripped.trim_end().to_string()));
            continue;
        }
        // The command after any `eval … &&` or environment settings before it.
        let last = line.rsplit("&&").next().unwrap_or(&line);
        let mut w = words(last);
        while w.first().is_some_and(|x| x.contains('=') && !x.starts_with('-')) {
            w.remove(0);
        }
        if w.last().is_some_and(|x| x == "&") {
            w.pop();
        }
        let (args, features) = match w.first().map(String::as_str) {
            Some("marionette" | "target/release/marionette") => (w[1..].to_vec(), Vec::new()),
            Some("cargo") if w.get(1).is_some_and(|x| x == "run") => {
                let Some(dashes) = w.iter().position(|x| x == "--") else {
                    continue;
                };
                if w[..dashes].iter().any(|x| x == "--example" || x == "--bin") {
                    continue;
                }
                let features = w[..dashes]
                    .iter()
                    .position(|x| x == "--features")
                    .and_then(|i| w.get(i + 1))
                    .map(|f| f.split(',').map(str::to_string).collect())
                    .unwrap_or_default();
                (w[dashes + 1..].to_vec(), features)
            }
            _ => continue,
        };
        if args.is_empty() {
            continue;
        }
        out.push(Documented {
            file: file.clone(),
            line: first,
            text: joined,
            args,
            features,
        });
    }
    out
}

fn documented() -> Vec<Documented> {
    let mut files = vec![root().join("README.md")];
    let mut guides: Vec<PathBuf> = std::fs::read_dir(root().join("docs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    guides.sort();
    files.extend(guides);
    files.push(root().join("BENCHMARKS.md"));
    files.iter().flat_map(|f| documented_in(f)).collect()
}

/// The subcommand path of `args` (`["sim", "serve"]`) and the `--help` text of it.
fn help_of(args: &[String], cache: &mut HashMap<Vec<String>, String>) -> (Vec<String>, String) {
    let mut path: Vec<String> = Vec::new();
    loop {
        let text = cache
            .entry(path.clone())
            .or_insert_with(|| {
                let out = common::bin().args(&path).arg("--help").output().unwrap();
                String::from_utf8_lossy(&out.stdout).into_owned()
            })
            .clone();
        // One more level when the next word is one of this level's commands.
        let next = args.get(path.len());
        let is_command = next.is_some_and(|n| {
            text.split("Commands:").nth(1).is_some_and(|list| {
                list.lines()
                    .skip(1)
                    .take_while(|l| !l.trim().is_empty())
                    .any(|l| l.split_whitespace().next() == Some(n.as_str()))
            })
        });
        if !is_command {
            return (path, text);
        }
        path.push(next.unwrap().clone());
    }
}

/// Why a documented command is not run here, if it is not.
fn not_run(d: &Documented) -> Option<&'static str> {
    if d.file == "BENCHMARKS.md" {
        return Some("a measurement: checked, not run");
    }
    let a = |s: &str| d.args.iter().any(|x| x == s || x.starts_with(&format!("{s}=")));
    let joined = d.args.join(" ");
    if joined.contains("PROFILE") || joined.contains('[') || joined.contains("/dev/pts/N") {
        return Some("a template");
    }
    if joined.contains("/dev/tty") {
        return Some("real hardware");
    }
    let simulated =
        d.features.iter().any(|f| f == "sim") || joined.contains("--bus sim") || d.args[0] == "sim";
    if simulated && !cfg!(feature = "sim") {
        return Some("needs the sim feature");
    }
    match d.args[0].as_str() {
        "studio" | "serve" => return Some("serves until stopped"),
        "sim" if d.args.get(1).is_some_and(|s| s == "serve") => return Some("serves until stopped"),
        "soak" => return Some("CI runs it as a step of its own"),
        _ => {}
    }
    if a("--write") {
        return Some("writes into the repository's profile");
    }
    if a("--ros2") || joined.contains("--targets ros2") {
        return Some("ROS 2 (tests/ros2.rs runs it against a DDS peer)");
    }
    if joined.contains("udp://") {
        return Some("waits for UDP targets");
    }
    None
}

/// Every documented command names a command and options that exist and files the repository
/// has; those that need nothing outside this machine run and exit 0.
#[test]
fn the_commands_in_the_readme_and_the_guides_work_as_written() {
    let all = documented();
    assert!(all.len() >= 50, "{} commands found", all.len());
    let mut helps = HashMap::new();
    let mut problems = Vec::new();
    for d in &all {
        let (path, help) = help_of(&d.args, &mut helps);
        if path.is_empty() || help.is_empty() {
            problems.push(format!("{}:{}: no such command: {}", d.file, d.line, d.text));
            continue;
        }
        for w in &d.args[path.len()..] {
            let option = w.split('=').next().unwrap();
            let known = if option.starts_with("--") {
                help.split(|c: char| !(c.is_alphanumeric() || c == '-' || c == '_'))
                    .any(|t| t == option)
            } else if option.len() == 2 && option.starts_with('-') && option != "--" {
                help.contains(&format!("{option},")) || help.contains(&format!("{option} "))
            } else {
                true
            };
            if !known {
                problems.push(format!(
                    "{}:{}: `{}` has no option {option}",
                    d.file,
                    d.line,
                    path.join(" ")
                ));
            }
            let repo_file = ["data/", "firmware-profile/", "sim/models/"]
                .iter()
                .any(|p| w.starts_with(p));
            if repo_file && !root().join(w).exists() {
                problems.push(format!("{}:{}: no file {w}", d.file, d.line));
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));

    // Run from a scratch directory that sees the repository's data, profiles and models, so
    // what the commands write lands there.
    let scratch = common::tempdir("docs-commands");
    for dir in ["data", "firmware-profile", "sim"] {
        let link = scratch.join(dir);
        if !link.exists() {
            std::os::unix::fs::symlink(root().join(dir), &link).unwrap();
        }
    }
    let (mut ran, mut skipped) = (0, Vec::new());
    for d in &all {
        if let Some(why) = not_run(d) {
            skipped.push(format!("{}:{} ({why})", d.file, d.line));
            continue;
        }
        let out = common::bin()
            .args(&d.args)
            .current_dir(&scratch)
            .stdin(std::process::Stdio::null())
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}:{}: `{}` exited {:?}:\n{}",
            d.file,
            d.line,
            d.text,
            out.status.code(),
            String::from_utf8_lossy(&out.stderr)
        );
        ran += 1;
    }
    println!(
        "{} documented commands checked against --help, {ran} run; not run: {}",
        all.len(),
        skipped.join(", ")
    );
    assert!(ran >= 30, "{ran} commands run");
}

/// The command scanner itself: continuation lines, comments, `eval … &&`, environment
/// settings, `cargo run --features`.
#[test]
fn documented_commands_are_read_as_a_shell_reads_them() {
    let dir = common::tempdir("docs-scan");
    let md = dir.join("x.md");
    std::fs::write(
        &md,
        "text\n```sh\n# a comment\nROS_DOMAIN_ID=7 target/release/marionette play a.toml \\\n    b.asf --rate 250   # why\n\
         eval \"$(sim/fetch-mujoco.sh)\" && cargo run --release --features sim -- play p.toml --bus sim\n\
         cargo run --release --example ik_compare\nmarionette serve p.toml &\n```\n\n```text\nmarionette not-shell\n```\n",
    )
    .unwrap();
    let found = documented_in(&md);
    let args: Vec<Vec<String>> = found.iter().map(|d| d.args.clone()).collect();
    assert_eq!(
        args,
        vec![
            vec!["play", "a.toml", "b.asf", "--rate", "250"],
            vec!["play", "p.toml", "--bus", "sim"],
            vec!["serve", "p.toml"],
        ]
        .into_iter()
        .map(|v| v.into_iter().map(String::from).collect::<Vec<_>>())
        .collect::<Vec<_>>()
    );
    assert_eq!(found[0].line, 4);
    assert_eq!(found[1].features, vec!["sim".to_string()]);
}

/// The keys `src/profile.rs` reads into `struct RawNAME { … }`, in order.
fn keys_of_struct(source: &str, name: &str) -> Vec<String> {
    let start = source
        .find(&format!("struct {name} {{"))
        .unwrap_or_else(|| panic!("no struct {name} in src/profile.rs"));
    let body = &source[start..];
    let body = &body[body.find('{').unwrap() + 1..body.find("\n}").unwrap()];
    body.lines()
        .map(str::trim)
        .filter(|l| !l.starts_with('#') && !l.starts_with("//"))
        .filter_map(|l| l.split_once(':').map(|(k, _)| k.trim().to_string()))
        .collect()
}

/// The rig profile reference lists exactly the keys the loader reads, section by section, and
/// its complete example loads.
#[test]
fn the_rig_profile_reference_lists_every_key_the_loader_reads() {
    let source = std::fs::read_to_string(root().join("src/profile.rs")).unwrap();
    let guide = std::fs::read_to_string(root().join("docs/rig-profile.md")).unwrap();
    // Each section's table: the keys in its first column.
    let mut documented: HashMap<String, Vec<String>> = HashMap::new();
    let mut section = String::new();
    for line in guide.lines() {
        if let Some(h) = line.strip_prefix("## ").or_else(|| line.strip_prefix("### ")) {
            section = h.split('`').nth(1).unwrap_or(h).to_string();
        } else if let Some(cell) = line.strip_prefix("| `") {
            let key = cell.split('`').next().unwrap().to_string();
            documented.entry(section.clone()).or_default().push(key);
        }
    }
    let sections = [
        ("[rig]", "RawRig"),
        ("[bus]", "RawBus"),
        ("[[bone]]", "RawBone"),
        ("[[servo]]", "RawServo"),
        ("[retarget]", "RawRetarget"),
        ("[retarget.left_arm]", "RawChain"),
    ];
    let mut problems = Vec::new();
    for (section, raw) in sections {
        let mut read = keys_of_struct(&source, raw);
        if raw == "RawRetarget" {
            // Its subtables have sections of their own.
            read.retain(|k| {
                !["names", "left_arm", "right_arm", "left_leg", "right_leg", "head"].contains(&k.as_str())
            });
        }
        let listed = documented.get(section).cloned().unwrap_or_default();
        for k in &read {
            if !listed.contains(k) {
                problems.push(format!("{section} `{k}` is read but not in docs/rig-profile.md"));
            }
        }
        for k in &listed {
            if !read.contains(k) {
                problems.push(format!("{section} `{k}` is documented but not read"));
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));

    // The complete example loads, and uses every key outside the retarget map (its servos
    // follow bones: `joint` drives a servo from a retarget map's robot joint).
    let example = guide
        .split("```toml\n")
        .nth(1)
        .and_then(|s| s.split("```").next())
        .expect("a ```toml block in docs/rig-profile.md");
    let profile = marionette::profile::Profile::parse(example, Path::new("docs/rig-profile.md"))
        .unwrap_or_else(|e| panic!("the example profile does not load: {e}"));
    assert_eq!(profile.servos.len(), 2);
    for (_, raw) in &sections[..4] {
        for k in keys_of_struct(&source, raw).into_iter().filter(|k| k != "joint") {
            assert!(
                example
                    .lines()
                    .any(|l| l.trim_start().starts_with(&format!("{k} ="))),
                "the example leaves out `{k}`"
            );
        }
    }
}
