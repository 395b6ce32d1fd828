//! The host side of Protocol 2.0: any bytes as the replies on the line, to every kind of
//! transaction the loop and the start-up make; and the packet decoder on its own, where every
//! packet that decodes must encode back to the same bytes.
#![no_main]

use std::io;
use std::time::Duration;

use libfuzzer_sys::fuzz_target;
use marionette::bus::packet::{wire_time, PacketBus, Transport};
use marionette::bus::ServoBus;
use marionette::protocol;

/// A line whose replies are the fuzzer's bytes, in pieces of the sizes the input chooses.
struct FuzzLine<'a> {
    bytes: &'a [u8],
    piece: usize,
    clock: Duration,
}

impl Transport for FuzzLine<'_> {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.clock += wire_time(bytes.len(), 1_000_000);
        Ok(())
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        let n = self.piece.min(self.bytes.len()).min(buf.len());
        if n == 0 {
            self.clock += timeout;
            return Ok(0);
        }
        buf[..n].copy_from_slice(&self.bytes[..n]);
        self.bytes = &self.bytes[n..];
        self.clock += wire_time(n, 1_000_000);
        Ok(n)
    }

    fn now(&self) -> Duration {
        self.clock
    }

    fn baud(&self) -> u32 {
        1_000_000
    }
}

fuzz_target!(|data: &[u8]| {
    let mut params = [0u8; 1024];
    if let Ok((packet, total)) = protocol::decode(data, &mut params) {
        let mut again = [0u8; 2048];
        let n = protocol::encode(packet.id, packet.instruction, packet.params, &mut again)
            .expect("a decoded packet encodes");
        assert_eq!(
            &again[..n],
            &data[..total],
            "decode then encode gives the same bytes"
        );
    }

    let Some((&choice, replies)) = data.split_first() else {
        return;
    };
    let mut bus = PacketBus::new(
        FuzzLine {
            bytes: replies,
            piece: 1 + usize::from(choice >> 3),
            clock: Duration::ZERO,
        },
        Duration::from_micros(500),
    );
    let ids = [1u8, 2, 3];
    match choice & 7 {
        0 => {
            let _ = bus.ping(1);
        }
        1 => {
            let _ = bus.scan();
        }
        2 => {
            let mut out = [0u8; 4];
            let _ = bus.read(2, 132, &mut out);
        }
        3 => {
            let _ = bus.write(3, 116, &[0, 8, 0, 0]);
        }
        4 => {
            let mut out = [0i32; 3];
            let _ = bus.read_positions(&ids, &mut out);
        }
        5 => {
            let _ = bus.reboot(1);
        }
        6 => {
            let _ = bus.hardware_error(2);
        }
        _ => {
            // Many transactions in a row: what is left of one reply must not answer the next.
            let mut out = [0i32; 3];
            for _ in 0..8 {
                let _ = bus.read_positions(&ids, &mut out);
                let _ = bus.write_goals(&ids, &[2048, 2048, 2048]);
            }
        }
    }
});
