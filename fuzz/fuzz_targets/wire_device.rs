//! The device side: any bytes as instruction traffic to a chain of virtual servos. Every
//! reply is a well-formed status packet, no goal outside a servo's limits is taken, and the
//! servos keep finite positions.
#![no_main]

use libfuzzer_sys::fuzz_target;
use marionette::device::{Chain, Received, Receiver, Replies, VirtualServo, MAX_PACKET};
use marionette::protocol::{self, instruction};
use marionette::servo::{addr, MODELS};

fuzz_target!(|data: &[u8]| {
    let mut chain = Chain::new();
    for (k, id) in [1u8, 2, 3].into_iter().enumerate() {
        let _ = chain.add(VirtualServo::new(id, &MODELS[k % MODELS.len()], 2048));
    }
    let mut rx = Receiver::default();
    let mut out = vec![0u8; 8 * MAX_PACKET];
    let mut replies = Replies::new();
    let mut packet = [0u8; MAX_PACKET];
    // The bytes arrive in pieces whose sizes the input's first byte chooses.
    let Some((&piece, mut rest)) = data.split_first() else {
        return;
    };
    let piece = 1 + usize::from(piece);
    while !rest.is_empty() {
        let n = piece.min(rest.len());
        rx.push(&rest[..n]);
        rest = &rest[n..];
        while let Received::Packet(raw) = rx.next_packet() {
            let len = raw.len();
            packet[..len].copy_from_slice(raw);
            rx.consume(len);
            let before: Vec<i32> = chain.servos().iter().map(|s| s.goal_tick()).collect();
            if chain.handle(&packet[..len], &mut out, &mut replies).is_err() {
                continue;
            }
            for (s, old) in chain.servos().iter().zip(before) {
                let (goal, lo, hi) = (
                    s.goal_tick(),
                    s.register(addr::MIN_POSITION_LIMIT, 4) as i32,
                    s.register(addr::MAX_POSITION_LIMIT, 4) as i32,
                );
                // A new goal is inside the limits, or is where the servo stands (a reboot).
                if goal != old && goal != s.present_tick() {
                    assert!((lo..=hi).contains(&goal), "goal {goal} taken outside {lo}..={hi}");
                }
            }
            for r in &replies {
                let mut params = [0u8; MAX_PACKET];
                let (status, used) =
                    protocol::decode(&out[r.start..r.start + r.len], &mut params).expect("a reply decodes");
                assert_eq!(used, r.len);
                assert_eq!(status.instruction, instruction::STATUS);
                assert_eq!(status.id, r.id);
            }
        }
        chain.step(0.001);
        for s in chain.servos() {
            assert!(s.position().is_finite(), "positions stay finite");
        }
    }
});
