//! AMC reader against the bundled skeleton of subject 16: any bytes; a motion that loads runs
//! FK on every frame and writes back to AMC that loads again with the same frames.
#![no_main]

use libfuzzer_sys::fuzz_target;
use marionette::fk::{fk64, Pose64};
use marionette::formats::{amc, text_from_bytes};
use marionette::motion::frame_to_radians;

mod bundled;
use bundled::skeleton;

fuzz_target!(|data: &[u8]| {
    let text = match text_from_bytes(data.to_vec()) {
        Ok(text) => text,
        Err(e) => return assert!(e.line > 0, "an error names its line: {e:?}"),
    };
    let skeleton = skeleton();
    let motion = match amc::parse(skeleton, &text) {
        Ok(motion) => motion,
        Err(e) => return assert!(e.line > 0, "an error names its line: {e:?}"),
    };
    let mut pose = Pose64::default();
    for frame in motion.frames() {
        fk64(skeleton, &frame_to_radians(skeleton, frame), &mut pose);
    }
    let mut written = Vec::new();
    amc::write(skeleton, &motion, &mut written).expect("writing to memory");
    let again = amc::parse(
        skeleton,
        std::str::from_utf8(&written).expect("AMC is written as UTF-8"),
    )
    .unwrap_or_else(|e| panic!("a written motion must read back: {e}"));
    assert_eq!(again.len(), motion.len());
});
