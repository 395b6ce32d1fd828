//! BVH reader: any bytes, as `info`/`convert` read a file; a motion that loads runs FK on its
//! first and last frames.
#![no_main]

use libfuzzer_sys::fuzz_target;
use marionette::fk::{fk64, Pose64};
use marionette::formats::{bvh, text_from_bytes};
use marionette::motion::frame_to_radians;

fuzz_target!(|data: &[u8]| {
    let text = match text_from_bytes(data.to_vec()) {
        Ok(text) => text,
        Err(e) => return assert!(e.line > 0, "an error names its line: {e:?}"),
    };
    let (file, motion) = match bvh::parse(&text, 1.0) {
        Ok(loaded) => loaded,
        Err(e) => return assert!(e.line > 0, "an error names its line: {e:?}"),
    };
    let skeleton = &file.skeleton;
    let mut pose = Pose64::default();
    for i in [0, motion.len().saturating_sub(1)] {
        if i < motion.len() {
            fk64(skeleton, &frame_to_radians(skeleton, motion.frame(i)), &mut pose);
        }
    }
});
