//! Rig profile loader: any bytes as a TOML profile; one that loads builds its rig against the
//! bundled skeleton (and without one) and plans its bus budget.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use marionette::budget::plan;
use marionette::formats::text_from_bytes;
use marionette::profile::Profile;

mod bundled;
use bundled::skeleton;

fuzz_target!(|data: &[u8]| {
    let text = match text_from_bytes(data.to_vec()) {
        Ok(text) => text,
        Err(e) => return assert!(e.line > 0, "an error names its line: {e:?}"),
    };
    let profile = match Profile::parse(&text, Path::new("fuzz.toml")) {
        Ok(profile) => profile,
        Err(e) => return assert!(e.line > 0, "an error names its line: {e:?}"),
    };
    for rig in [profile.rig(None), profile.rig(Some(skeleton()))] {
        match rig {
            Ok(rig) => {
                for s in &rig.servos {
                    assert!(s.min_tick <= s.max_tick, "a rig servo's limits are in order");
                }
            }
            Err(e) => assert!(
                e.text_error().is_some_and(|t| t.line > 0),
                "a rig error names its line: {e}"
            ),
        }
    }
    let _ = plan(&profile.bus, profile.servos.len(), Some(100.0));
});
