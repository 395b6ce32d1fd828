//! Rig profile loader: any bytes as a TOML profile; one that loads builds its rig against the
//! bundled skeleton (and without one) and plans its bus budget.
#![no_main]

use std::path::Path;
use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;
use marionette::budget::plan;
use marionette::formats::{asf, text_from_bytes};
use marionette::profile::Profile;
use marionette::skeleton::Skeleton;

fn skeleton() -> &'static Skeleton {
    static SKELETON: OnceLock<Skeleton> = OnceLock::new();
    SKELETON.get_or_init(|| {
        asf::parse(include_str!("../../data/cmu/16.asf"))
            .expect("the bundled skeleton loads")
            .skeleton
    })
}

fuzz_target!(|data: &[u8]| {
    let Ok(text) = text_from_bytes(data.to_vec()) else {
        return;
    };
    let Ok(profile) = Profile::parse(&text, Path::new("fuzz.toml")) else {
        return;
    };
    let _ = profile.rig(None);
    if let Ok(rig) = profile.rig(Some(skeleton())) {
        for s in &rig.servos {
            assert!(s.min_tick <= s.max_tick, "a rig servo's limits are in order");
        }
    }
    let _ = plan(&profile.bus, profile.servos.len(), Some(100.0));
});
