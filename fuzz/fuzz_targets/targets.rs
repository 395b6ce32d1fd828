//! Target lines (CSV and JSON lines) as `follow` reads a file, stdin or UDP: a track that loads
//! has finite targets at finite times in order.
#![no_main]

use libfuzzer_sys::fuzz_target;
use marionette::control::sources::{parse_target_line, TargetTrack};
use marionette::formats::text_from_bytes;

const EFFECTORS: [&str; 4] = ["lradius", "rradius", "ltibia", "rtibia"];

fuzz_target!(|data: &[u8]| {
    let effectors: Vec<String> = EFFECTORS.iter().map(|s| s.to_string()).collect();
    // A datagram or stdin line is read on its own, whatever else is in the input.
    for line in String::from_utf8_lossy(data).lines() {
        if let Ok(Some((t, targets))) = parse_target_line(line, &effectors) {
            assert!(t.is_finite());
            assert!(targets.iter().all(|x| x.is_finite()));
        }
    }
    let text = match text_from_bytes(data.to_vec()) {
        Ok(text) => text,
        Err(e) => return assert!(e.line > 0, "an error names its line: {e:?}"),
    };
    let track = match TargetTrack::parse(&text, &effectors) {
        Ok(track) => track,
        Err(e) => return assert!(e.line > 0, "an error names its line: {e:?}"),
    };
    let mut last = f64::NEG_INFINITY;
    for (t, targets) in &track.samples {
        assert!(t.is_finite() && *t >= last, "times finite and in order");
        assert!(targets.iter().all(|x| x.is_finite()), "targets finite");
        last = *t;
    }
    assert!(track.duration().is_finite());
});
