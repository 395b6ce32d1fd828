//! Writes seed inputs for the wire fuzz targets (`fuzz/`): the real traffic of each transaction
//! the `wire_host` target makes, against a chain of three virtual servos (ids 1–3).
//!
//! `cargo run --example wire_seeds -- DIR` writes `DIR/wire_host/*` (a choice byte, then the
//! replies the host read) and `DIR/wire_device/*` (a piece-size byte, then the instructions the
//! host sent).

use std::io;
use std::path::PathBuf;
use std::time::Duration;

use marionette::bus::packet::{PacketBus, Transport};
use marionette::bus::virtual_chain::InProcess;
use marionette::bus::ServoBus;
use marionette::device::{Chain, VirtualServo};
use marionette::servo::MODELS;

/// A transport that keeps a copy of every byte sent and received.
struct Recorder {
    link: InProcess,
    sent: Vec<u8>,
    received: Vec<u8>,
}

impl Transport for Recorder {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.sent.extend_from_slice(bytes);
        self.link.send(bytes)
    }
    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        let n = self.link.recv(buf, timeout)?;
        self.received.extend_from_slice(&buf[..n]);
        Ok(n)
    }
    fn now(&self) -> Duration {
        self.link.now()
    }
    fn baud(&self) -> u32 {
        self.link.baud()
    }
}

fn main() -> io::Result<()> {
    let dir = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "fuzz/corpus".into()));
    let (host, device) = (dir.join("wire_host"), dir.join("wire_device"));
    std::fs::create_dir_all(&host)?;
    std::fs::create_dir_all(&device)?;
    let ids = [1u8, 2, 3];
    for choice in 0u8..8 {
        let mut chain = Chain::new();
        for (k, id) in ids.into_iter().enumerate() {
            let _ = chain.add(VirtualServo::new(id, &MODELS[k % MODELS.len()], 2048));
        }
        let recorder = Recorder {
            link: InProcess::new(chain, 1_000_000),
            sent: Vec::new(),
            received: Vec::new(),
        };
        let mut bus = PacketBus::new(recorder, Duration::from_micros(500));
        let mut out = [0i32; 3];
        let mut bytes = [0u8; 4];
        let _ = match choice {
            0 => bus.ping(1).map(drop),
            1 => bus.scan().map(drop),
            2 => bus.read(2, 132, &mut bytes),
            3 => bus.write(3, 116, &[0, 8, 0, 0]),
            4 => bus.read_positions(&ids, &mut out),
            5 => bus.reboot(1),
            6 => bus.hardware_error(2).map(drop),
            _ => (0..8).try_for_each(|_| {
                bus.read_positions(&ids, &mut out)?;
                bus.write_goals(&ids, &[2048, 2100, 1990])
            }),
        };
        let rec = bus.link();
        // Choice in the low three bits; the pieces the replies arrive in: 16 bytes.
        let mut h = vec![choice | (15 << 3)];
        h.extend_from_slice(&rec.received);
        std::fs::write(host.join(format!("seed-{choice}")), h)?;
        let mut d = vec![31u8];
        d.extend_from_slice(&rec.sent);
        std::fs::write(device.join(format!("seed-{choice}")), d)?;
    }
    println!("wire seeds written under {}", dir.display());
    Ok(())
}
