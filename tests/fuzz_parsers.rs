//! Property test: mutations of the real CMU files (truncation, deleted, duplicated and swapped
//! lines, garbage bytes, NaN, infinities, huge numbers, unknown names, cycles, duplicate bones)
//! give a clean error or a valid result — never a panic. A valid result must give finite FK on
//! every frame.
//!
//! 20,000 cases in all by default; `MARIONETTE_FUZZ_CASES=N` runs N per parser.

mod common;

use marionette::fk::{forward_kinematics, Pose};
use marionette::formats::{amc, asf, bvh, text_from_bytes};
use marionette::motion::Motion;
use marionette::skeleton::{Skeleton, MAX_CHANNELS};
use proptest::prelude::*;
use proptest::sample::Index;
use std::sync::OnceLock;

const SPECIAL: &[&str] = &[
    "NaN",
    "nan",
    "inf",
    "-inf",
    "1e39",
    "-1e308",
    "1e-320",
    "3.4e38",
    "99999999999999999999",
    "-0",
    "",
    "(",
    ")",
    "((",
    "root",
    "lfemur",
    "lhumerus",
    "zz",
    "end",
    "begin",
    ":bonedata",
    ":hierarchy",
    ":root",
    "#",
    "0x10",
    "1,5",
    "1e",
    "XYQ",
    "rx",
    "l",
    "tx",
    "ZYX",
    "{",
    "}",
    "JOINT",
    "End",
    "CHANNELS",
    "6",
    "1000000",
    "-1",
];

#[derive(Clone, Debug)]
enum Mutation {
    Truncate(Index),
    DeleteLine(Index),
    DuplicateLines(Index, usize),
    SwapLines(Index, Index),
    ReplaceToken(Index, Index, Index),
    InsertLine(Index, Index),
    Garbage(Index, Vec<u8>),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        any::<Index>().prop_map(Mutation::Truncate),
        any::<Index>().prop_map(Mutation::DeleteLine),
        (any::<Index>(), 1usize..12).prop_map(|(i, n)| Mutation::DuplicateLines(i, n)),
        (any::<Index>(), any::<Index>()).prop_map(|(a, b)| Mutation::SwapLines(a, b)),
        (any::<Index>(), any::<Index>(), any::<Index>())
            .prop_map(|(l, t, s)| Mutation::ReplaceToken(l, t, s)),
        (any::<Index>(), any::<Index>()).prop_map(|(l, s)| Mutation::InsertLine(l, s)),
        (any::<Index>(), proptest::collection::vec(any::<u8>(), 1..8))
            .prop_map(|(i, b)| Mutation::Garbage(i, b)),
    ]
}

/// Hierarchy lines that make cycles or second parents, and bone names from the file.
const EXTRA_LINES: &[&str] = &[
    "ltibia lfemur",
    "lfemur ltibia",
    "head root",
    "root root",
    "lhumerus lhumerus",
    "  begin",
    "  end",
    "lfemur 1 2 3 4",
    "root 0 0 0 0 0 0 0",
    "1",
    "JOINT x { OFFSET 0 0 0 CHANNELS 3 Xrotation Yrotation Zrotation }",
    "    limits (-inf inf)",
    "    dof rx ry rz tx ty tz l",
    "    axis 1e9 -1e9 0 ZXZ",
];

fn apply(text: &str, muts: &[Mutation]) -> Vec<u8> {
    let mut lines: Vec<String> = text.split('\n').map(str::to_string).collect();
    let mut garbage: Vec<(Index, Vec<u8>)> = Vec::new();
    let mut cut: Option<Index> = None;
    for m in muts {
        if lines.is_empty() {
            break;
        }
        match m {
            Mutation::Truncate(i) => cut = Some(*i),
            Mutation::DeleteLine(i) => {
                lines.remove(i.index(lines.len()));
            }
            Mutation::DuplicateLines(i, n) => {
                let a = i.index(lines.len());
                let b = (a + n).min(lines.len());
                let copy: Vec<String> = lines[a..b].to_vec();
                for (k, l) in copy.into_iter().enumerate() {
                    lines.insert(b + k, l);
                }
            }
            Mutation::SwapLines(a, b) => {
                let (a, b) = (a.index(lines.len()), b.index(lines.len()));
                lines.swap(a, b);
            }
            Mutation::ReplaceToken(l, t, s) => {
                let li = l.index(lines.len());
                let mut toks: Vec<String> = lines[li].split_whitespace().map(str::to_string).collect();
                if !toks.is_empty() {
                    let ti = t.index(toks.len());
                    toks[ti] = SPECIAL[s.index(SPECIAL.len())].to_string();
                    lines[li] = format!("  {}", toks.join(" "));
                }
            }
            Mutation::InsertLine(l, s) => {
                let li = l.index(lines.len());
                lines.insert(li, EXTRA_LINES[s.index(EXTRA_LINES.len())].to_string());
            }
            Mutation::Garbage(i, b) => garbage.push((*i, b.clone())),
        }
    }
    let mut bytes = lines.join("\n").into_bytes();
    for (i, g) in garbage {
        let at = i.index(bytes.len() + 1);
        bytes.splice(at..at, g);
    }
    if let Some(i) = cut {
        bytes.truncate(i.index(bytes.len() + 1));
    }
    bytes
}

fn cases(default: u32) -> u32 {
    std::env::var("MARIONETTE_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn config(default: u32) -> ProptestConfig {
    ProptestConfig {
        cases: cases(default),
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

fn assert_fk_finite(s: &Skeleton, m: Option<&Motion>) {
    let mut c = [0.0f32; MAX_CHANNELS];
    let mut p = Pose::new();
    forward_kinematics(s, &c, &mut p).unwrap();
    assert!(
        p.tip[..s.len()].iter().all(|v| v.is_finite()),
        "rest pose not finite"
    );
    if let Some(m) = m {
        for i in 0..m.len() {
            m.channels_into(s, i, &mut c);
            forward_kinematics(s, &c, &mut p).unwrap();
            assert!(
                p.tip[..s.len()].iter().all(|v| v.is_finite()),
                "frame {i} not finite"
            );
        }
    }
}

/// The first `frames` frames of a motion file, as real text.
fn head_of(name: &str, marker: impl Fn(&str) -> bool, frames: usize) -> String {
    let text = common::read(name);
    let mut out = String::new();
    let mut seen = 0;
    for line in text.split_inclusive('\n') {
        if marker(line) {
            seen += 1;
            if seen > frames {
                break;
            }
        }
        out.push_str(line);
    }
    out
}

fn fixtures() -> &'static (String, Skeleton, String, String) {
    static F: OnceLock<(String, Skeleton, String, String)> = OnceLock::new();
    F.get_or_init(|| {
        let asf_text = common::read("16.asf");
        let s = asf::parse(&asf_text).unwrap().skeleton;
        let amc_text = head_of("16_15.amc", |l| l.trim().parse::<u32>().is_ok(), 20);
        let bvh_full = common::read("16_15.bvh");
        let header_end = bvh_full.find("Frame Time").unwrap();
        let mut bvh_text = bvh_full[..header_end].replace("Frames:\t471", "Frames:\t20");
        bvh_text.push_str(
            &bvh_full[header_end..]
                .split_inclusive('\n')
                .take(21)
                .collect::<String>(),
        );
        (asf_text, s, amc_text, bvh_text)
    })
}

proptest! {
    #![proptest_config(config(8_000))]
    #[test]
    fn mutated_asf_gives_error_or_valid_skeleton(muts in proptest::collection::vec(mutation(), 1..5)) {
        let (asf_text, _, _, _) = fixtures();
        let bytes = apply(asf_text, &muts);
        if let Ok(text) = text_from_bytes(bytes) {
            match asf::parse(&text) {
                Ok(f) => assert_fk_finite(&f.skeleton, None),
                Err(e) => prop_assert!(!e.message.is_empty() && e.line > 0),
            }
        }
    }
}

proptest! {
    #![proptest_config(config(8_000))]
    #[test]
    fn mutated_amc_gives_error_or_valid_motion(muts in proptest::collection::vec(mutation(), 1..5)) {
        let (_, s, amc_text, _) = fixtures();
        let bytes = apply(amc_text, &muts);
        if let Ok(text) = text_from_bytes(bytes) {
            match amc::parse(s, &text) {
                Ok(m) => assert_fk_finite(s, Some(&m)),
                Err(e) => prop_assert!(!e.message.is_empty() && e.line > 0, "{e:?}"),
            }
        }
    }
}

proptest! {
    #![proptest_config(config(4_000))]
    #[test]
    fn mutated_bvh_gives_error_or_valid_motion(muts in proptest::collection::vec(mutation(), 1..5)) {
        let (_, _, _, bvh_text) = fixtures();
        let bytes = apply(bvh_text, &muts);
        if let Ok(text) = text_from_bytes(bytes) {
            match bvh::parse(&text, 1.0 / 2.54) {
                Ok((f, m)) => assert_fk_finite(&f.skeleton, Some(&m)),
                Err(e) => prop_assert!(!e.message.is_empty() && e.line > 0, "{e:?}"),
            }
        }
    }
}

#[test]
fn fixtures_parse_unmutated() {
    let (asf_text, s, amc_text, bvh_text) = fixtures();
    assert!(asf::parse(asf_text).is_ok());
    assert_eq!(amc::parse(s, amc_text).unwrap().len(), 20);
    assert_eq!(bvh::parse(bvh_text, 1.0 / 2.54).unwrap().1.len(), 20);
}

/// Empty, blank and header-only files: every reader names a line (an empty file: line 1;
/// a file that ends too early: its last line), and the message says what was expected.
#[test]
fn files_that_end_early_name_their_last_line() {
    use marionette::control::sources::TargetTrack;
    use marionette::profile::Profile;
    let (_, s, _, _) = fixtures();
    let effectors = vec!["lradius".to_string()];
    let cases: [(&str, &str, u32); 12] = [
        ("asf", "", 1),
        ("asf", "\n\n", 1),
        ("amc", "", 1),
        ("amc", ":FULLY-SPECIFIED\r\n:DEGREES\r\n", 2),
        ("bvh", "", 1),
        ("bvh", "HIERARCHY\n", 1),
        ("profile", "", 1),
        ("profile", "[rig]\nname = \"x\"\n[bus]\nbaud = 1000000\n", 4),
        ("targets", "", 1),
        ("targets", "t,effector,x,y,z\n# nothing yet\n", 2),
        ("targets", "0,lradius,1,2,inf\n", 1),
        ("amc", "1\nroot 0 0 0 0 0 1e300\n", 2),
    ];
    for (kind, text, line) in cases {
        let e = match kind {
            "asf" => asf::parse(text).err(),
            "amc" => amc::parse(s, text).err(),
            "bvh" => bvh::parse(text, 1.0).err(),
            "profile" => Profile::parse(text, std::path::Path::new("p.toml")).err(),
            _ => TargetTrack::parse(text, &effectors).err(),
        }
        .unwrap_or_else(|| panic!("{kind} {text:?} must not load"));
        assert!(e.line >= line && e.line > 0, "{kind} {text:?}: {e:?}");
        assert!(e.message.contains("expected"), "{kind} {text:?}: {e:?}");
    }
}
