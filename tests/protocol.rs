//! The project's Protocol 2.0 codec: byte-exact against the e-manual's example packets,
//! stuffing checked exhaustively against a straightforward reference, and a decoder that never
//! panics on any bytes.

use marionette::protocol::{
    crc16, decode, encode, instruction as inst, stuff, stuffed_len, unstuff, CodecError,
};
use proptest::prelude::*;

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

fn encoded(id: u8, instruction: u8, params: &[u8]) -> Vec<u8> {
    let mut buf = [0u8; 256];
    let n = encode(id, instruction, params, &mut buf).unwrap();
    buf[..n].to_vec()
}

/// (what, id, instruction, parameters, the e-manual's packet)
const EXAMPLES: &[(&str, u8, u8, &str, &str)] = &[
    ("ping", 1, inst::PING, "", "FF FF FD 00 01 03 00 01 19 4E"),
    (
        "ping status (model 1030, fw 38)",
        1,
        inst::STATUS,
        "00 06 04 26",
        "FF FF FD 00 01 07 00 55 00 06 04 26 65 5D",
    ),
    (
        "read 4 bytes at 132",
        1,
        inst::READ,
        "84 00 04 00",
        "FF FF FD 00 01 07 00 02 84 00 04 00 1D 15",
    ),
    (
        "read status (166)",
        1,
        inst::STATUS,
        "00 A6 00 00 00",
        "FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0",
    ),
    (
        "write 512 at 116",
        1,
        inst::WRITE,
        "74 00 00 02 00 00",
        "FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89",
    ),
    (
        "empty status",
        1,
        inst::STATUS,
        "00",
        "FF FF FD 00 01 04 00 55 00 A1 0C",
    ),
    ("reboot", 1, inst::REBOOT, "", "FF FF FD 00 01 03 00 08 2F 4E"),
    (
        "factory reset all but id",
        1,
        inst::FACTORY_RESET,
        "01",
        "FF FF FD 00 01 04 00 06 01 A1 E6",
    ),
    (
        "sync read 4 bytes at 132 from 1, 2",
        0xFE,
        inst::SYNC_READ,
        "84 00 04 00 01 02",
        "FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA",
    ),
    (
        "sync read status id 2 (2079)",
        2,
        inst::STATUS,
        "00 1F 08 00 00",
        "FF FF FD 00 02 08 00 55 00 1F 08 00 00 BA BE",
    ),
    (
        "sync write 150 to 1, 170 to 2 at 116",
        0xFE,
        inst::SYNC_WRITE,
        "74 00 04 00 01 96 00 00 00 02 AA 00 00 00",
        "FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00 82 87",
    ),
];

#[test]
fn encodes_the_e_manual_examples_byte_for_byte() {
    for (what, id, instruction, params, packet) in EXAMPLES {
        assert_eq!(encoded(*id, *instruction, &hex(params)), hex(packet), "{what}");
    }
}

#[test]
fn decodes_the_e_manual_examples() {
    for (what, id, instruction, params, packet) in EXAMPLES {
        let bytes = hex(packet);
        let mut out = [0u8; 64];
        let (p, used) = decode(&bytes, &mut out).unwrap();
        assert_eq!(used, bytes.len(), "{what}");
        assert_eq!(
            (p.id, p.instruction, p.params),
            (*id, *instruction, hex(params).as_slice()),
            "{what}"
        );
    }
    let status = hex("FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0");
    let mut out = [0u8; 64];
    let (p, _) = decode(&status, &mut out).unwrap();
    let (error, data) = p.status().unwrap();
    assert_eq!(error, 0);
    assert_eq!(i32::from_le_bytes(data.try_into().unwrap()), 166);
}

/// The specification read literally: after every `FF FF FD` in the data insert `FD`. (Two
/// matches cannot overlap: a match ends in FD, and the next needs FF FF before its FD.)
fn reference_stuff(data: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    for (i, &b) in data.iter().enumerate() {
        out.push(b);
        if i >= 2 && data[i - 2..=i] == [0xFF, 0xFF, 0xFD] {
            out.push(0xFD);
        }
    }
    out
}

/// Every sequence of length 0..=max over the alphabet.
fn all_sequences(alphabet: &[u8], max: usize) -> Vec<Vec<u8>> {
    let mut all = vec![Vec::new()];
    let mut frontier = vec![Vec::new()];
    for _ in 0..max {
        let mut next = Vec::new();
        for s in &frontier {
            for &b in alphabet {
                let mut t: Vec<u8> = s.clone();
                t.push(b);
                next.push(t);
            }
        }
        all.extend(next.iter().cloned());
        frontier = next;
    }
    all
}

#[test]
fn stuffing_matches_the_reference_on_every_short_payload() {
    let payloads = all_sequences(&[0x00, 0x01, 0xFD, 0xFF], 8);
    assert_eq!(payloads.len(), 87_381); // 87,380 non-empty + the empty one
    let mut divergences = 0;
    let mut buf = [0u8; 32];
    let mut back = [0u8; 32];
    let mut changed = 0;
    for p in &payloads {
        let want = reference_stuff(p);
        let n = stuff(p, &mut buf).unwrap();
        if buf[..n] != want[..] || stuffed_len(p) != want.len() {
            divergences += 1;
        }
        changed += usize::from(want.len() != p.len());
        let m = unstuff(&want, &mut back).unwrap();
        if back[..m] != p[..] {
            divergences += 1;
        }
        // Through whole packets too: the parameters survive encode → decode.
        let packet = encoded(7, inst::WRITE, p);
        let mut params = [0u8; 32];
        let (d, _) = decode(&packet, &mut params).unwrap();
        if d.params != p.as_slice() {
            divergences += 1;
        }
    }
    assert_eq!(divergences, 0);
    assert!(changed > 1000, "{changed} payloads need stuffing");
}

/// FACTS.md: dynamixel2 0.9.1 neither stuffs nor unstuffs `FF FF FF FD`. The spec (and this
/// codec) stuffs it; an unstuffed copy of it inside a packet is a malformed packet.
#[test]
fn the_ff_ff_ff_fd_pattern_is_stuffed_and_its_unstuffed_form_rejected() {
    // Present Velocity −1 then a Present Position whose low byte is FD, as a status packet.
    let data = hex("00 FF FF FF FF FD 01 00 00");
    let packet = encoded(1, inst::STATUS, &data);
    assert!(
        packet.windows(5).any(|w| w == [0xFF, 0xFF, 0xFF, 0xFD, 0xFD]),
        "stuffed: {packet:02X?}"
    );
    // The same packet with the pattern left unstuffed (what dynamixel2 0.9.1 would send),
    // with a CRC that matches its bytes: the decoder must refuse it, not misread it.
    let mut bad = vec![0xFF, 0xFF, 0xFD, 0x00, 0x01];
    let len = (1 + data.len() + 2) as u16;
    bad.extend_from_slice(&len.to_le_bytes());
    bad.push(inst::STATUS);
    bad.extend_from_slice(&data);
    let crc = crc16(&bad);
    bad.extend_from_slice(&crc.to_le_bytes());
    let mut out = [0u8; 32];
    assert_eq!(
        decode(&bad, &mut out).map(|(p, _)| p.params.len()),
        Err(CodecError::BadStuffing)
    );
}

#[test]
fn corrupt_packets_are_reported() {
    let good = hex("FF FF FD 00 01 07 00 02 84 00 04 00 1D 15");
    let mut out = [0u8; 32];
    let mut bad_crc = good.clone();
    bad_crc[9] ^= 1;
    assert!(matches!(
        decode(&bad_crc, &mut out),
        Err(CodecError::BadCrc { .. })
    ));
    assert_eq!(
        decode(&good[..10], &mut out).map(|r| r.1),
        Err(CodecError::Incomplete)
    );
    assert_eq!(
        decode(&good[1..], &mut out).map(|r| r.1),
        Err(CodecError::BadHeader)
    );
    let mut bad_len = good.clone();
    bad_len[5] = 2;
    assert_eq!(
        decode(&bad_len, &mut out).map(|r| r.1),
        Err(CodecError::BadLength)
    );
    let mut small = [0u8; 2];
    assert_eq!(
        decode(&good, &mut small).map(|r| r.1),
        Err(CodecError::BufferFull)
    );
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 20_000, failure_persistence: None, ..ProptestConfig::default() })]
    #[test]
    fn decoding_any_bytes_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..64), header in any::<bool>()) {
        let mut input = if header { vec![0xFF, 0xFF, 0xFD, 0x00] } else { Vec::new() };
        input.extend_from_slice(&bytes);
        let mut out = [0u8; 64];
        if let Ok((p, used)) = decode(&input, &mut out) {
            prop_assert!(used <= input.len());
            prop_assert!(p.params.len() <= used);
        }
    }

    #[test]
    fn encode_decode_round_trip(id in any::<u8>(), ins in any::<u8>(), params in proptest::collection::vec(any::<u8>(), 0..40)) {
        let mut buf = [0u8; 128];
        let n = encode(id, ins, &params, &mut buf).unwrap();
        let mut out = [0u8; 64];
        let (p, used) = decode(&buf[..n], &mut out).unwrap();
        prop_assert_eq!(used, n);
        prop_assert_eq!((p.id, p.instruction, p.params), (id, ins, params.as_slice()));
    }
}
