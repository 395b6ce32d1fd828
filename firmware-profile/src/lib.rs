//! The embedded build of marionette's core: `no_std`, no heap, for Cortex-M
//! (`thumbv7em-none-eabihf`).
//!
//! It bundles the CMU subject-16 skeleton as text and reads it with the core ASF reader at
//! start-up, then computes forward kinematics per frame into a caller-owned [`Pose`]. Rig and
//! servo profiles (TOML, read by the std build) live beside this crate in `firmware-profile/`.
//!
//! Without hardware, the board can answer Protocol 2.0 itself: [`virtual_op3`] is a chain of
//! the ROBOTIS OP3's 20 virtual XM430-W350 (ids as in `robotis-op3.toml`), and [`serve`] turns
//! received bytes into the status packets to send back.
#![no_std]
#![deny(unsafe_code)]
#![warn(missing_docs)]

pub use marionette_core::asf::{parse_asf, AsfError};
pub use marionette_core::fk::{forward_kinematics, Pose, ShortFrame};
pub use marionette_core::skeleton::{Skeleton, MAX_CHANNELS};

pub use marionette_core::device::{Chain, Received, Receiver, Replies, VirtualServo};

/// The OP3's servo ids, 1…20, in `robotis-op3.toml` order (all XM430-W350).
pub const OP3_IDS: core::ops::RangeInclusive<u8> = 1..=20;

/// The ROBOTIS OP3's servos as a virtual chain, every horn at tick 2048.
#[must_use]
pub fn virtual_op3() -> Chain {
    let model = marionette_core::servo::model_by_name("XM430-W350");
    let mut chain = Chain::new();
    if let Some(model) = model {
        for id in OP3_IDS {
            // 20 servos fit: the chain holds MAX_SERVOS (64).
            let _ = chain.add(VirtualServo::new(id, model, 2048));
        }
    }
    chain
}

/// Feeds received bytes to the chain and writes every status packet due into `out`; returns
/// the bytes written. Return delays are the caller's to honour (see [`Replies`]).
pub fn serve(chain: &mut Chain, rx: &mut Receiver, input: &[u8], out: &mut [u8]) -> usize {
    rx.push(input);
    let mut used = 0;
    let mut packet = [0u8; marionette_core::device::MAX_PACKET];
    let mut replies = Replies::new();
    while let Received::Packet(raw) = rx.next_packet() {
        let n = raw.len();
        packet[..n].copy_from_slice(raw);
        rx.consume(n);
        let mut buf = [0u8; 2 * marionette_core::device::MAX_PACKET];
        if chain.handle(&packet[..n], &mut buf, &mut replies).is_ok() {
            for r in &replies {
                if used + r.len <= out.len() {
                    out[used..used + r.len].copy_from_slice(&buf[r.start..r.start + r.len]);
                    used += r.len;
                }
            }
        }
    }
    used
}

/// The bundled skeleton (CMU subject 16; see `data/cmu/README.md` for its attribution).
pub const BUNDLED_ASF: &str = include_str!("../../data/cmu/16.asf");

/// Reads the bundled skeleton.
///
/// # Errors
/// Never for the bundled file; the error type is the core reader's.
pub fn bundled_skeleton() -> Result<Skeleton, AsfError<'static>> {
    parse_asf(BUNDLED_ASF).map(|a| a.skeleton)
}

/// One frame (radians, file units) to bone positions: the core's FK, eq. (1)–(5).
///
/// # Errors
/// [`ShortFrame`] when the frame vector is shorter than the skeleton needs.
pub fn pose_frame(skeleton: &Skeleton, channels: &[f32], pose: &mut Pose) -> Result<(), ShortFrame> {
    forward_kinematics(skeleton, channels, pose)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bundled_skeleton_reads_and_poses() {
        let s = bundled_skeleton().unwrap();
        assert_eq!(s.len(), 31);
        let channels = [0.0f32; MAX_CHANNELS];
        let mut pose = Pose::new();
        pose_frame(&s, &channels, &mut pose).unwrap();
        // At rest the head is above the feet.
        let head = s.find("head").unwrap();
        let toes = s.find("ltoes").unwrap();
        assert!(pose.tip[head].y > pose.tip[toes].y + 20.0);
        assert!(pose_frame(&s, &channels[..10], &mut pose).is_err());
    }

    #[test]
    fn virtual_op3_answers_a_sync_read_split_across_reads() {
        use marionette_core::protocol::{decode, encode, instruction, BROADCAST_ID};
        let mut chain = virtual_op3();
        let mut rx = Receiver::default();
        let mut request = [0u8; 64];
        let params = [132, 0, 4, 0, 1, 2, 3];
        let n = encode(BROADCAST_ID, instruction::SYNC_READ, &params, &mut request).unwrap();
        let mut out = [0u8; 256];
        // The request arrives in two pieces.
        assert_eq!(serve(&mut chain, &mut rx, &request[..5], &mut out), 0);
        let used = serve(&mut chain, &mut rx, &request[5..n], &mut out);
        assert_eq!(used, 3 * 15);
        let mut at = 0;
        for id in 1..=3u8 {
            let mut p = [0u8; 16];
            let (packet, len) = decode(&out[at..used], &mut p).unwrap();
            assert_eq!(
                (packet.id, packet.status()),
                (id, Some((0, &[0x00, 0x08, 0, 0][..])))
            );
            at += len;
        }
    }
}
