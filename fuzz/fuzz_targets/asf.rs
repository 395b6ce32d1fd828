//! ASF reader: any bytes, as `info`/`fk` read a file; a skeleton that loads runs FK and writes
//! back to ASF that loads again with the same bones.
#![no_main]

use libfuzzer_sys::fuzz_target;
use marionette::fk::{fk64, Pose64};
use marionette::formats::{asf, text_from_bytes};

fuzz_target!(|data: &[u8]| {
    let text = match text_from_bytes(data.to_vec()) {
        Ok(text) => text,
        Err(e) => return assert!(e.line > 0, "an error names its line: {e:?}"),
    };
    let file = match asf::parse(&text) {
        Ok(file) => file,
        Err(e) => return assert!(e.line > 0, "an error names its line: {e:?}"),
    };
    let skeleton = &file.skeleton;
    let mut pose = Pose64::default();
    fk64(skeleton, &vec![0.0; skeleton.channel_count()], &mut pose);
    let mut written = Vec::new();
    asf::write(&file, &mut written).expect("writing to memory");
    let again = asf::parse(std::str::from_utf8(&written).expect("ASF is written as UTF-8"))
        .unwrap_or_else(|e| panic!("a written skeleton must read back: {e}"));
    assert_eq!(again.skeleton.len(), skeleton.len());
    assert_eq!(again.skeleton.channel_count(), skeleton.channel_count());
});
