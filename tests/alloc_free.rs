//! Proof, with a counting global allocator, that the hot paths allocate nothing: forward
//! kinematics over a whole clip (frame conversion included) and the core ASF reader.

mod common;

use marionette::fk::{forward_kinematics, Pose};
use marionette::formats::{amc, asf};
use marionette::skeleton::MAX_CHANNELS;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Counting;

thread_local! {
    // Per thread, so that other tests running in parallel do not count.
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

#[allow(unsafe_code)]
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> u64 {
    ALLOCATIONS.with(Cell::get)
}

#[test]
fn counter_sees_allocations() {
    let before = allocations();
    let v = std::hint::black_box(vec![1u8; 64]);
    assert!(allocations() > before);
    drop(v);
}

#[test]
fn fk_of_whole_clips_allocates_nothing() {
    for (a, m) in [("16.asf", "16_15.amc"), ("01.asf", "01_01.amc")] {
        let file = asf::load(&common::data(a)).unwrap();
        let s = &file.skeleton;
        let motion = amc::load(s, &common::data(m)).unwrap();
        let mut channels = [0.0f32; MAX_CHANNELS];
        let mut pose = Pose::new();
        let mut checksum = 0.0f32;
        let before = allocations();
        for i in 0..motion.len() {
            motion.channels_into(s, i, &mut channels);
            forward_kinematics(s, &channels, &mut pose).unwrap();
            checksum += pose.tip[s.len() - 1].y;
        }
        let during = allocations() - before;
        assert_eq!(
            during,
            0,
            "{m}: {during} allocations over {} frames",
            motion.len()
        );
        assert!(std::hint::black_box(checksum).is_finite());
    }
}

#[test]
fn core_asf_reader_allocates_nothing() {
    let text = common::read("16.asf");
    let before = allocations();
    let parsed = marionette::asf::parse_asf(&text).map(|a| a.skeleton.len());
    let during = allocations() - before;
    assert_eq!(parsed, Ok(31));
    assert_eq!(during, 0);
}
