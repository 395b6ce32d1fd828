//! One interface for everything that feeds the loop: a clip, a target file, target lines from
//! stdin or UDP, and (in their own modules) ROS 2 topics and the studio's drags.
//!
//! A [`Source`] is driven one of two ways, and does not know which:
//! * in real time by [`spawn_real_time`], a thread on the loop's clock: a *paced* source's
//!   inputs are made shortly before they are due, a *live* source sends what arrives as it
//!   arrives;
//! * in lockstep by [`super::lockstep::FeedingClock`], on the simulator's time: every input due
//!   by a tick is sent just before it, so the same inputs give the same run.

use std::net::UdpSocket;
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use crossbeam_channel::Receiver;

use super::input::{Input, InputSender, Payload, SendError, Target};
use super::sources::{
    parse_target_line, ClipPlayer, PlayerCommand, ProducerReport, TargetTrack, MAX_DATAGRAM_BYTES,
};
use crate::clock::SystemClock;
use crate::schedule::Clock;
use crate::skeleton::MAX_CHANNELS;

/// How far ahead of its due time a paced input is made in real time: long enough for a sleeping
/// thread to wake and to ride out a few milliseconds of preemption on a loaded machine (a late
/// sample would be passed over for the next), short enough for the input to be fresh.
pub const LEAD_NS: u64 = 10_000_000;

/// The loop's tick grid: tick `k` is due at `start_ns + k·period_ns` on the loop's clock.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Grid {
    /// The first tick.
    pub start_ns: u64,
    /// The period.
    pub period_ns: u64,
}

/// Where a source's inputs go, and how: the real-time driver lets a paced source wait while the
/// channel is full; in lockstep nothing may wait (the loop runs in the same thread), and the
/// channel holds the whole preview.
#[derive(Debug)]
pub struct Sink<'a> {
    tx: &'a InputSender,
    wait: bool,
}

impl Sink<'_> {
    /// Sends a paced input (waiting in real time while the channel is full). Returns whether an
    /// older input was dropped for it.
    ///
    /// # Errors
    /// The loop stopped.
    pub fn send(&self, msg: Input) -> Result<bool, SendError> {
        if self.wait {
            self.tx.send_wait(msg).map(|()| false)
        } else {
            self.tx.send_newest(msg)
        }
    }

    /// Sends a live input: never waits, drops the oldest queued one when the channel is full.
    ///
    /// # Errors
    /// The loop stopped.
    pub fn send_newest(&self, msg: Input) -> Result<bool, SendError> {
        self.tx.send_newest(msg)
    }

    /// Whether the loop has stopped taking inputs.
    #[must_use]
    pub fn stopped(&self) -> bool {
        self.tx.stopped()
    }

    /// The flag [`Sink::stopped`] reads, for a thread that waits on something else.
    #[must_use]
    pub fn stop_flag(&self) -> Arc<std::sync::atomic::AtomicBool> {
        self.tx.stop_flag()
    }
}

/// Something that produces the loop's inputs (module documentation).
pub trait Source: Send {
    /// A short name (its thread's).
    fn name(&self) -> &'static str;

    /// True when inputs come as they arrive (stdin, UDP, ROS 2, the studio); false when each
    /// has a due time on the grid (a clip, a target file).
    fn live(&self) -> bool;

    /// True when it can run on a simulator's time (paced sources; the studio paces the
    /// simulation to the wall clock itself).
    fn runs_in_lockstep(&self) -> bool {
        !self.live()
    }

    /// A paced source: when its next input is due, `None` once it has ended. A live source:
    /// `None`.
    fn next_due(&self, grid: Grid) -> Option<u64>;

    /// Called once with the loop's clock before the first [`Source::feed`] in real time.
    fn begin(&mut self, _clock: SystemClock) {}

    /// Sends every input due at or before `until_ns` (made at `now_ns`). A live source driven in
    /// real time gets `until_ns = u64::MAX` and returns when its input ends or
    /// [`Sink::stopped`]. Returns false once the source has ended.
    fn feed(&mut self, grid: Grid, until_ns: u64, now_ns: u64, sink: &Sink<'_>) -> bool;

    /// What was sent.
    fn report(&self) -> ProducerReport;

    /// A paced source that holds its first input before the rest (a clip's pre-roll) holds it
    /// at least `seconds`: the servos' move to the first pose takes that long. Others ignore
    /// it.
    fn hold_first(&mut self, _seconds: f64) {}

    /// The targets of the first input, when they are known before the run (a target file):
    /// the pose the run starts towards.
    fn first_targets(&self) -> Option<&[Target]> {
        None
    }
}

impl<S: Source + ?Sized> Source for Box<S> {
    fn name(&self) -> &'static str {
        (**self).name()
    }
    fn live(&self) -> bool {
        (**self).live()
    }
    fn runs_in_lockstep(&self) -> bool {
        (**self).runs_in_lockstep()
    }
    fn hold_first(&mut self, seconds: f64) {
        (**self).hold_first(seconds);
    }
    fn first_targets(&self) -> Option<&[Target]> {
        (**self).first_targets()
    }
    fn next_due(&self, grid: Grid) -> Option<u64> {
        (**self).next_due(grid)
    }
    fn begin(&mut self, clock: SystemClock) {
        (**self).begin(clock);
    }
    fn feed(&mut self, grid: Grid, until_ns: u64, now_ns: u64, sink: &Sink<'_>) -> bool {
        (**self).feed(grid, until_ns, now_ns, sink)
    }
    fn report(&self) -> ProducerReport {
        (**self).report()
    }
}

/// In lockstep: `source` feeding `tx` without waiting.
pub(super) fn lockstep_feed(
    source: &mut dyn Source,
    grid: Grid,
    until_ns: u64,
    now_ns: u64,
    tx: &InputSender,
) -> bool {
    source.feed(grid, until_ns, now_ns, &Sink { tx, wait: false })
}

/// Drives `source` in real time in a thread of its own: a paced input is made
/// [`LEAD_NS`] (at least two periods) plus `preview_ns` (the look-ahead takes inputs that far
/// ahead) before it is due on `clock`; a live source is fed until it ends. The thread ends with
/// the source or when the loop stops, and returns what was sent.
///
/// # Errors
/// When the thread cannot be started.
pub fn spawn_real_time(
    mut source: Box<dyn Source>,
    tx: InputSender,
    mut clock: SystemClock,
    grid: Grid,
    preview_ns: u64,
) -> std::io::Result<JoinHandle<ProducerReport>> {
    let lead = (2 * grid.period_ns).max(LEAD_NS) + preview_ns;
    std::thread::Builder::new()
        .name(source.name().into())
        .spawn(move || {
            source.begin(clock);
            let sink = Sink { tx: &tx, wait: true };
            while !tx.stopped() {
                let until = if source.live() {
                    u64::MAX
                } else {
                    let Some(due) = source.next_due(grid) else {
                        break;
                    };
                    let at = due.saturating_sub(lead);
                    let now = clock.now_ns();
                    if at > now {
                        std::thread::sleep(Duration::from_nanos(at - now));
                    }
                    due
                };
                if !source.feed(grid, until, clock.now_ns(), &sink) {
                    break;
                }
            }
            source.report()
        })
}

/// A clip played at the loop's rate: sample `k` is due at tick `k`; player commands (pause,
/// seek, speed) are taken between samples.
#[derive(Debug)]
pub struct ClipSource {
    player: ClipPlayer,
    commands: Option<Receiver<PlayerCommand>>,
    next: u64,
    channels: usize,
    report: ProducerReport,
}

impl ClipSource {
    /// Plays `player` (its rate is the loop's), taking `commands` when given.
    #[must_use]
    pub fn new(player: ClipPlayer, commands: Option<Receiver<PlayerCommand>>) -> ClipSource {
        let channels = player.channel_count().min(MAX_CHANNELS);
        let player_pre_roll = player.pre_roll_samples();
        ClipSource {
            player,
            commands,
            next: 0,
            channels,
            report: ProducerReport {
                pre_roll: player_pre_roll,
                ..ProducerReport::default()
            },
        }
    }
}

impl Source for ClipSource {
    fn name(&self) -> &'static str {
        "clip-player"
    }
    fn live(&self) -> bool {
        false
    }
    fn next_due(&self, grid: Grid) -> Option<u64> {
        Some(grid.start_ns + self.next * grid.period_ns)
    }
    fn feed(&mut self, grid: Grid, until_ns: u64, now_ns: u64, sink: &Sink<'_>) -> bool {
        let mut buf = [0.0; MAX_CHANNELS];
        loop {
            let due = grid.start_ns + self.next * grid.period_ns;
            if due > until_ns {
                return true;
            }
            if let Some(rx) = &self.commands {
                while let Ok(c) = rx.try_recv() {
                    self.player.control(c);
                }
            }
            let Some(t) = self.player.next_sample(&mut buf[..self.channels]) else {
                return false;
            };
            match sink.send(Input::frame(self.next, due, now_ns, &buf[..self.channels], t)) {
                Ok(dropped) => self.report.dropped += u64::from(dropped),
                Err(_) => return false,
            }
            self.report.sent += 1;
            self.next += 1;
        }
    }
    fn report(&self) -> ProducerReport {
        self.report
    }
    fn hold_first(&mut self, seconds: f64) {
        // Only before the first sample: a pre-roll under way is not lengthened.
        if self.next == 0 && seconds / self.player.period_s() > self.player.pre_roll_samples() as f64 {
            self.player.set_pre_roll(seconds);
            self.report.pre_roll = self.player.pre_roll_samples();
        }
    }
}

/// Targets from a file: the sample at track time `t` is due `t − t₀` after the first tick;
/// looping starts over one 120 Hz period after the last sample (so the last and first samples
/// of two passes are not due at once).
#[derive(Debug)]
pub struct TrackSource {
    track: Arc<TargetTrack>,
    looping: bool,
    /// How long the first sample is held before the rest follow, ns ([`Source::hold_first`]).
    hold_ns: u64,
    next: usize,
    pass: u64,
    seq: u64,
    report: ProducerReport,
}

impl TrackSource {
    /// Plays `track` once, or over and over.
    #[must_use]
    pub fn new(track: TargetTrack, looping: bool) -> TrackSource {
        TrackSource {
            track: Arc::new(track),
            looping,
            hold_ns: 0,
            next: 0,
            pass: 0,
            seq: 0,
            report: ProducerReport::default(),
        }
    }

    fn due(&self, grid: Grid) -> Option<u64> {
        let t0 = self.track.samples.first()?.0;
        let (t, _) = self.track.samples.get(self.next)?;
        let pass_ns = ((self.track.duration() + 1.0 / 120.0) * 1e9) as u64;
        let held = if self.next == 0 && self.pass == 0 {
            0
        } else {
            self.hold_ns
        };
        Some(grid.start_ns + held + self.pass * pass_ns + ((t - t0) * 1e9) as u64)
    }
}

impl Source for TrackSource {
    fn name(&self) -> &'static str {
        "target-track"
    }
    fn live(&self) -> bool {
        false
    }
    fn next_due(&self, grid: Grid) -> Option<u64> {
        self.due(grid)
    }
    fn hold_first(&mut self, seconds: f64) {
        // Only before the first sample is sent; a longer hold asked before stands.
        if self.next == 0 && self.pass == 0 && seconds.is_finite() && seconds > 0.0 {
            self.hold_ns = self.hold_ns.max((seconds * 1e9) as u64);
        }
    }
    fn first_targets(&self) -> Option<&[Target]> {
        self.track.samples.first().map(|(_, t)| &t[..])
    }
    fn feed(&mut self, grid: Grid, until_ns: u64, now_ns: u64, sink: &Sink<'_>) -> bool {
        while let Some(due) = self.due(grid) {
            if due > until_ns {
                return true;
            }
            let msg = Input {
                seq: self.seq,
                due_ns: due,
                made_ns: now_ns,
                payload: Payload::Targets(self.track.samples[self.next].1.clone()),
            };
            match sink.send(msg) {
                Ok(dropped) => self.report.dropped += u64::from(dropped),
                Err(_) => return false,
            }
            self.report.sent += 1;
            self.seq += 1;
            self.next += 1;
            if self.next == self.track.samples.len() && self.looping {
                self.next = 0;
                self.pass += 1;
            }
        }
        false
    }
    fn report(&self) -> ProducerReport {
        self.report
    }
}

/// Target lines (the file formats' lines, time ignored) as they come, each due at once, the
/// newest winning: stdin's lines, or any other reader's.
pub struct LineSource {
    lines: Box<dyn Iterator<Item = String> + Send>,
    effectors: Vec<String>,
    clock: Option<SystemClock>,
    seq: u64,
    report: ProducerReport,
}

impl std::fmt::Debug for LineSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LineSource")
            .field("effectors", &self.effectors)
            .finish_non_exhaustive()
    }
}

impl LineSource {
    /// Lines from standard input for `effectors`. Ends at the end of input; a stop of the loop is
    /// seen between lines.
    #[must_use]
    pub fn stdin(effectors: Vec<String>) -> LineSource {
        let lines = std::iter::from_fn(|| {
            let mut line = String::new();
            match std::io::stdin().read_line(&mut line) {
                Ok(0) | Err(_) => None,
                Ok(_) => Some(line.trim_end_matches(['\n', '\r']).to_string()),
            }
        });
        LineSource::new(lines, effectors)
    }

    /// Lines from `lines` for `effectors`.
    #[must_use]
    pub fn new(lines: impl Iterator<Item = String> + Send + 'static, effectors: Vec<String>) -> LineSource {
        LineSource {
            lines: Box::new(lines),
            effectors,
            clock: None,
            seq: 0,
            report: ProducerReport::default(),
        }
    }
}

/// Reads `text`'s target lines into the sink; false once the loop has stopped.
fn send_lines<'l>(
    lines: impl Iterator<Item = &'l str>,
    effectors: &[String],
    seq: &mut u64,
    now_ns: u64,
    sink: &Sink<'_>,
    report: &mut ProducerReport,
) -> bool {
    for line in lines {
        if sink.stopped() {
            return false;
        }
        match parse_target_line(line, effectors) {
            Ok(Some((_, targets))) => {
                let msg = Input {
                    seq: *seq,
                    due_ns: 0,
                    made_ns: now_ns,
                    payload: Payload::Targets(targets),
                };
                *seq += 1;
                match sink.send_newest(msg) {
                    Ok(dropped) => {
                        report.sent += 1;
                        report.dropped += u64::from(dropped);
                    }
                    Err(_) => return false,
                }
            }
            Ok(None) => {}
            Err(_) => report.bad_lines += 1,
        }
    }
    true
}

/// The loop's clock, for stamping live inputs as they arrive.
fn stamp(clock: Option<&mut SystemClock>, fallback: u64) -> u64 {
    clock.map_or(fallback, |c| c.now_ns())
}

impl Source for LineSource {
    fn name(&self) -> &'static str {
        "targets-lines"
    }
    fn live(&self) -> bool {
        true
    }
    fn next_due(&self, _grid: Grid) -> Option<u64> {
        None
    }
    fn begin(&mut self, clock: SystemClock) {
        self.clock = Some(clock);
    }
    fn feed(&mut self, _grid: Grid, _until_ns: u64, now_ns: u64, sink: &Sink<'_>) -> bool {
        // Each line stamped when it was read (on the loop's clock after `begin`).
        for line in self.lines.by_ref() {
            let made = stamp(self.clock.as_mut(), now_ns);
            if !send_lines(
                std::iter::once(line.as_str()),
                &self.effectors,
                &mut self.seq,
                made,
                sink,
                &mut self.report,
            ) {
                return false;
            }
        }
        false
    }
    fn report(&self) -> ProducerReport {
        self.report
    }
}

/// Target lines as UDP datagrams (one or more lines each, at most [`MAX_DATAGRAM_BYTES`]; a
/// longer one is refused whole), each due at once, the newest winning. Ends when the loop stops.
#[derive(Debug)]
pub struct UdpSource {
    socket: UdpSocket,
    effectors: Vec<String>,
    clock: Option<SystemClock>,
    seq: u64,
    report: ProducerReport,
}

impl UdpSource {
    /// Datagrams on `socket` for `effectors`.
    ///
    /// # Errors
    /// The socket's read timeout cannot be set (the stop is seen between reads).
    pub fn new(socket: UdpSocket, effectors: Vec<String>) -> std::io::Result<UdpSource> {
        socket.set_read_timeout(Some(Duration::from_millis(20)))?;
        Ok(UdpSource {
            socket,
            effectors,
            clock: None,
            seq: 0,
            report: ProducerReport::default(),
        })
    }

    /// The address it listens on.
    ///
    /// # Errors
    /// The socket's.
    pub fn local_addr(&self) -> std::io::Result<std::net::SocketAddr> {
        self.socket.local_addr()
    }
}

impl Source for UdpSource {
    fn name(&self) -> &'static str {
        "targets-udp"
    }
    fn live(&self) -> bool {
        true
    }
    fn next_due(&self, _grid: Grid) -> Option<u64> {
        None
    }
    fn begin(&mut self, clock: SystemClock) {
        self.clock = Some(clock);
    }
    fn feed(&mut self, _grid: Grid, _until_ns: u64, now_ns: u64, sink: &Sink<'_>) -> bool {
        // One byte more than the limit: a datagram that fills it is over the limit.
        let mut buf = [0u8; MAX_DATAGRAM_BYTES + 1];
        while !sink.stopped() {
            let n = match self.socket.recv(&mut buf) {
                Ok(n) => n,
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock
                            | std::io::ErrorKind::TimedOut
                            | std::io::ErrorKind::Interrupted
                    ) =>
                {
                    continue
                }
                Err(_) => return false,
            };
            if n > MAX_DATAGRAM_BYTES {
                self.report.oversized += 1;
                continue;
            }
            let Ok(text) = std::str::from_utf8(&buf[..n]) else {
                self.report.bad_lines += 1;
                continue;
            };
            let made = stamp(self.clock.as_mut(), now_ns);
            if !send_lines(
                text.lines(),
                &self.effectors,
                &mut self.seq,
                made,
                sink,
                &mut self.report,
            ) {
                return false;
            }
        }
        false
    }
    fn report(&self) -> ProducerReport {
        self.report
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::input::input_channel;
    use glam::DVec3;

    /// A track of `n` samples 10 ms apart, one effector moving along x.
    fn track(n: usize) -> TargetTrack {
        TargetTrack {
            samples: (0..n)
                .map(|k| {
                    let mut targets = heapless::Vec::new();
                    let position = DVec3::new(k as f64, 0.0, 0.0);
                    let _ = targets.push(Target {
                        effector: 0,
                        position,
                        direction: None,
                    });
                    (0.01 * k as f64, targets)
                })
                .collect(),
        }
    }

    /// The dues a track source sends, fed to the end.
    fn dues(mut source: TrackSource) -> Vec<u64> {
        let (tx, mut port) = input_channel(64);
        let grid = Grid {
            start_ns: 1_000,
            period_ns: 1_000_000,
        };
        let more = source.feed(grid, u64::MAX, 0, &Sink { tx: &tx, wait: false });
        assert!(!more, "a track that does not loop ends");
        std::iter::from_fn(|| port.next_due(u64::MAX).map(|m| m.due_ns)).collect()
    }

    #[test]
    fn a_held_track_sends_its_first_sample_at_once_and_the_rest_after_the_hold() {
        let plain = dues(TrackSource::new(track(4), false));
        assert_eq!(plain, [1_000, 10_001_000, 20_001_000, 30_001_000]);
        let mut held = TrackSource::new(track(4), false);
        assert_eq!(held.first_targets().map(<[Target]>::len), Some(1));
        held.hold_first(1.5);
        held.hold_first(0.5);
        let held = dues(held);
        assert_eq!(held[0], plain[0], "the first sample is due at the start");
        for (h, p) in held.iter().zip(&plain).skip(1) {
            assert_eq!(
                h - p,
                1_500_000_000,
                "the rest follow 1.5 s later, spaced as before"
            );
        }
        // A hold asked once the track has begun changes nothing.
        let mut late = TrackSource::new(track(4), false);
        let (tx, _port) = input_channel(64);
        let grid = Grid {
            start_ns: 0,
            period_ns: 1_000_000,
        };
        late.feed(grid, 0, 0, &Sink { tx: &tx, wait: false });
        late.hold_first(1.5);
        assert_eq!(late.next_due(grid), Some(10_000_000));
    }
}
