//! A virtual servo chain as a transport: in-process in virtual time, or served on a
//! pseudo-terminal so that real clients (`dynamixel2`, or `marionette` itself) talk to it.

use std::collections::VecDeque;
use std::io::{self, Read, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::faults::FaultInjector;
use super::packet::{wire_time, Transport};
use crate::device::{Chain, Received, Receiver, Replies, VirtualServo, MAX_PACKET};
use crate::profile::BusSection;
use crate::servo::MAX_SERVOS;

/// A chain with one servo per profiled id, each at `position` (or 2048), and the profile's
/// IMU board when it has one.
///
/// # Panics
/// Never: profiles hold at most [`crate::servo::MAX_SERVOS`] servos.
#[must_use]
pub fn chain_for(profile: BusSection<'_>, position: impl Fn(usize) -> i32) -> Chain {
    let mut chain = Chain::new();
    for (k, s) in profile.servos.iter().enumerate() {
        let mut servo = VirtualServo::new(s.id, s.model, position(k));
        // Set to the bus's baud and powered as the profile says, as the rig's servos are.
        servo.set_baud(profile.config.baud);
        servo.set_supply(s.supply_v);
        let _ = chain.add(servo);
    }
    if let Some(id) = profile.config.imu_board {
        chain.set_board(crate::sensor_board::SensorBoard::new(id));
    }
    chain
}

/// Makes `chain` wrong on purpose, to try `doctor` on it: `spec` is a comma-separated list of
/// `missing=ID` (taken off the bus), `extra=ID` (one more servo the profile does not name),
/// `model=ID:NAME` (another model at the id), `rdt=ID:MICROSECONDS`, `srl=ID:LEVEL`,
/// `mode=ID:OPERATING_MODE`, `max_limit=ID:TICK`, `velocity_limit=ID:UNITS`, `pwm_limit=ID:N`,
/// `baud=ID:BITS_PER_S` (heard only at that baud once the chain keeps to the line's, as
/// `serve` does), `temp=ID:CELSIUS` (warm from an earlier run; it heats and cools from there),
/// `supply=ID:VOLTS` and `hwerror=ID:BITS` (Hardware Error Status bits, e.g. 4 for
/// overheating).
///
/// # Errors
/// What is wrong with `spec`, as one line.
pub fn misconfigure(chain: &mut Chain, spec: &str) -> Result<(), String> {
    use crate::servo::addr;
    for item in spec.split(',').map(str::trim).filter(|i| !i.is_empty()) {
        let (what, rest) = item
            .split_once('=')
            .ok_or_else(|| format!("`{item}`: expected WHAT=ID or WHAT=ID:VALUE"))?;
        let (id, value) = rest.split_once(':').map_or((rest, None), |(i, v)| (i, Some(v)));
        let id: u8 = id
            .parse()
            .map_err(|_| format!("`{item}`: the id must be a number 0–252"))?;
        let number = |v: Option<&str>| -> Result<u32, String> {
            v.ok_or_else(|| format!("`{item}`: expected {what}={id}:VALUE"))?
                .parse()
                .map_err(|_| format!("`{item}`: the value must be a whole number"))
        };
        let poke = |chain: &mut Chain, address: u16, data: &[u8]| -> Result<(), String> {
            chain
                .servo_mut(id)
                .ok_or_else(|| format!("`{item}`: no servo {id} on the chain"))?
                .poke(address, data);
            Ok(())
        };
        match what {
            "missing" => {
                chain
                    .remove(id)
                    .ok_or_else(|| format!("`{item}`: no servo {id} on the chain"))?;
            }
            "extra" => {
                let model = chain.servos().first().map_or(&crate::servo::MODELS[2], |s| s.model());
                let mut servo = VirtualServo::new(id, model, 2048);
                // On the bus's baud, as its neighbours are.
                if let Some(first) = chain.servos().first() {
                    servo.set_baud(first.baud());
                }
                chain.add(servo).map_err(|e| format!("`{item}`: {e}"))?;
            }
            "model" => {
                let name = value.ok_or_else(|| format!("`{item}`: expected model={id}:NAME"))?;
                let model = crate::servo::model_by_name(name)
                    .ok_or_else(|| format!("`{item}`: unknown model {name}"))?;
                let was = chain
                    .remove(id)
                    .ok_or_else(|| format!("`{item}`: no servo {id} on the chain"))?;
                let mut servo = VirtualServo::new(id, model, 2048);
                servo.set_baud(was.baud());
                chain.add(servo).map_err(|e| format!("`{item}`: {e}"))?;
            }
            "rdt" => poke(chain, addr::RETURN_DELAY_TIME, &[(number(value)? / 2).min(254) as u8])?,
            "srl" => poke(chain, addr::STATUS_RETURN_LEVEL, &[number(value)?.min(2) as u8])?,
            "mode" => poke(chain, addr::OPERATING_MODE, &[number(value)?.min(16) as u8])?,
            "max_limit" => poke(chain, addr::MAX_POSITION_LIMIT, &number(value)?.min(4095).to_le_bytes())?,
            "velocity_limit" => poke(chain, addr::VELOCITY_LIMIT, &number(value)?.to_le_bytes())?,
            "pwm_limit" => poke(chain, addr::PWM_LIMIT, &(number(value)?.min(885) as u16).to_le_bytes())?,
            "baud" => chain
                .servo_mut(id)
                .ok_or_else(|| format!("`{item}`: no servo {id} on the chain"))?
                .set_baud(number(value)?),
            "temp" => chain
                .servo_mut(id)
                .ok_or_else(|| format!("`{item}`: no servo {id} on the chain"))?
                .set_temperature(f64::from(number(value)?.min(150))),
            "supply" => {
                let volts: f64 = value
                    .ok_or_else(|| format!("`{item}`: expected supply={id}:VOLTS"))?
                    .parse()
                    .map_err(|_| format!("`{item}`: the supply must be a number of volts"))?;
                chain
                    .servo_mut(id)
                    .ok_or_else(|| format!("`{item}`: no servo {id} on the chain"))?
                    .set_supply(volts);
            }
            "hwerror" => chain
                .servo_mut(id)
                .ok_or_else(|| format!("`{item}`: no servo {id} on the chain"))?
                .raise_hardware_error(number(value)?.min(255) as u8),
            _ => {
                return Err(format!(
                    "`{item}`: unknown; expected missing, extra, model, rdt, srl, mode, max_limit, velocity_limit, pwm_limit, baud, temp, supply or hwerror"
                ))
            }
        }
    }
    Ok(())
}

/// How a rig of `servos` servos is really mounted, unknown to its profile (seeded): for each
/// servo, its horn's tick when the rig stands in its reference pose (anywhere in the turn, the
/// 0/4095 seam included), the direction its joint turns for rising ticks, and a Homing Offset
/// someone left in it (a third of them), `(horn, direction, homing_offset)`.
#[must_use]
pub fn miscalibration(seed: u64, servos: usize) -> Vec<(i32, i8, i32)> {
    let mut rng = super::faults::Rng::new(seed);
    (0..servos)
        .map(|_| {
            let horn = rng.below(4096) as i32;
            let direction = if rng.below(2) == 0 { 1 } else { -1 };
            let homing = if rng.below(3) == 0 {
                rng.below(2049) as i32 - 1024
            } else {
                0
            };
            (horn, direction, homing)
        })
        .collect()
}

/// Mounts `chain`'s servos (in profile order) as `truth` says ([`miscalibration`]), the rig
/// standing in its reference pose: each horn at its tick, its Homing Offset in place.
pub fn miscalibrate(chain: &mut Chain, ids: &[u8], truth: &[(i32, i8, i32)]) {
    for (&id, &(horn, _, homing)) in ids.iter().zip(truth) {
        if let Some(servo) = chain.servo_mut(id) {
            servo.poke(crate::servo::addr::HOMING_OFFSET, &homing.to_le_bytes());
            servo.set_position(f64::from(horn));
        }
    }
}

/// What moves a chain's servos as time passes.
pub trait Plant {
    /// Lets `dt` seconds pass for the servos of `chain`.
    fn advance(&mut self, chain: &mut Chain, dt: f64);
}

/// The servos' own motion model ([`VirtualServo::step`]: profile velocity and acceleration,
/// no load).
#[derive(Clone, Copy, Debug, Default)]
pub struct ServoMotion;

impl Plant for ServoMotion {
    fn advance(&mut self, chain: &mut Chain, dt: f64) {
        chain.step(dt);
    }
}

/// Runs one instruction through the chain and the injector: the byte chunks to send, each
/// with its delay after the previous one.
fn respond(
    chain: &mut Chain,
    packet: &[u8],
    injector: Option<&mut FaultInjector>,
    out: &mut [u8],
    replies: &mut Replies,
    mut emit: impl FnMut(Duration, &[u8]),
) {
    if chain.handle(packet, out, replies).is_err() {
        return;
    }
    match injector {
        None => {
            for r in replies.iter() {
                emit(
                    Duration::from_micros(u64::from(r.delay_us)),
                    &out[r.start..r.start + r.len],
                );
            }
        }
        Some(inj) => {
            let mut after = Vec::new();
            let count = replies.len();
            for (k, r) in replies.iter().enumerate() {
                let hit = inj.apply(&out[r.start..r.start + r.len], k + 1 == count);
                let delay = u64::from(r.delay_us) + u64::from(hit.extra_delay_us);
                emit(Duration::from_micros(delay), &hit.bytes);
                after.extend_from_slice(&hit.after_burst);
            }
            // Stale bytes come with the burst's end: they are in the host's input buffer
            // before its next instruction.
            if !after.is_empty() {
                emit(Duration::ZERO, &after);
            }
        }
    }
}

/// The chain in-process, in virtual time, keeping line time as [`LineTiming`] describes: an
/// instruction goes on the wire when the line is free (half duplex) and takes its wire time
/// (the host does not wait for it, as a write to an adapter returns at once); each reply
/// follows its return delay and wire time and reaches the host the adapter's latency after its
/// last byte; waiting advances the clock. No thread, no sleeping, deterministic. Step the
/// servos with [`InProcess::advance`]; the plant moves them.
#[derive(Debug)]
pub struct InProcess<P: Plant = ServoMotion> {
    chain: Chain,
    plant: P,
    baud: u32,
    usb_latency: Duration,
    clock: Duration,
    /// When the last byte on the wire ends.
    line_free: Duration,
    /// The time up to which the servos have moved.
    stepped: Duration,
    rx: Receiver,
    pending: VecDeque<(Duration, u8)>,
    /// In real time: the wall-clock instant the clock counts from.
    wall: Option<Instant>,
    out: Box<[u8; 8 * MAX_PACKET]>,
    replies: Replies,
    /// Optional fault injection.
    pub injector: Option<FaultInjector>,
}

impl InProcess {
    /// A transport to `chain` at `baud`, the servos moved by their own motion model.
    #[must_use]
    pub fn new(chain: Chain, baud: u32) -> InProcess {
        InProcess::with_plant(chain, ServoMotion, baud)
    }
}

impl<P: Plant> InProcess<P> {
    /// A transport to `chain` at `baud`, the servos moved by `plant`.
    #[must_use]
    pub fn with_plant(chain: Chain, plant: P, baud: u32) -> InProcess<P> {
        InProcess {
            chain,
            plant,
            baud,
            usb_latency: Duration::ZERO,
            clock: Duration::ZERO,
            line_free: Duration::ZERO,
            stepped: Duration::ZERO,
            rx: Receiver::default(),
            pending: crate::resident::deque(16 * MAX_PACKET, (Duration::ZERO, 0)),
            wall: None,
            out: Box::new([0; 8 * MAX_PACKET]),
            replies: Replies::new(),
            injector: None,
        }
    }

    /// The same with the USB adapter's latency timer: a reply reaches the host `latency`
    /// after its last byte.
    #[must_use]
    pub fn with_usb_latency(mut self, latency: Duration) -> InProcess<P> {
        self.usb_latency = latency;
        self
    }

    /// The same in real time: the clock is the wall clock from now on, a reply reaches the
    /// host when the wall clock passes its time (the host waits for it, sleeping), and the
    /// servos move by the wall clock's time at each instruction and read. The line keeps its
    /// time exactly, with no serving thread to wake (the loop's bus for `--bus virtual`).
    #[must_use]
    pub fn real_time(mut self) -> InProcess<P> {
        self.wall = Some(Instant::now() - self.clock);
        self
    }

    /// The wall clock's time (real time), else the virtual clock's.
    fn wall_now(&self) -> Duration {
        self.wall.map_or(self.clock, |w| w.elapsed().max(self.clock))
    }

    /// The chain.
    #[must_use]
    pub fn chain(&self) -> &Chain {
        &self.chain
    }

    /// The chain, mutable (to step it, raise errors, move horns).
    pub fn chain_mut(&mut self) -> &mut Chain {
        &mut self.chain
    }

    /// The plant.
    #[must_use]
    pub fn plant(&self) -> &P {
        &self.plant
    }

    /// The plant, mutable.
    pub fn plant_mut(&mut self) -> &mut P {
        &mut self.plant
    }

    /// Lets `dt` of virtual time pass: the servos move, bytes in flight arrive.
    pub fn advance(&mut self, dt: Duration) {
        self.clock += dt;
        self.catch_up();
    }

    /// In real time, sleeps until the wall clock reaches `t` (on the clock's scale).
    fn wait_until(&self, t: Duration) {
        if let Some(w) = self.wall {
            sleep_until(w + t);
        }
    }

    /// Moves the servos up to the clock.
    fn catch_up(&mut self) {
        self.step_to(self.clock);
    }

    /// Moves the servos up to `t` (an instruction's arrival may lie ahead of the host's clock).
    fn step_to(&mut self, t: Duration) {
        if t > self.stepped {
            self.plant
                .advance(&mut self.chain, (t - self.stepped).as_secs_f64());
            self.stepped = t;
        }
    }
}

impl<P: Plant> Transport for InProcess<P> {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.clock = self.wall_now();
        // Input already arrived is flushed; bytes still in flight are not.
        while self.pending.front().is_some_and(|(t, _)| *t <= self.clock) {
            self.pending.pop_front();
        }
        // On the wire once the line is free; the servos act on it when its last byte is in.
        let arrived = self.clock.max(self.line_free) + wire_time(bytes.len(), self.baud);
        self.step_to(arrived);
        self.line_free = arrived;
        self.rx.push(bytes);
        while let Received::Packet(raw) = self.rx.next_packet() {
            let n = raw.len();
            let mut packet = [0u8; MAX_PACKET];
            packet[..n].copy_from_slice(raw);
            self.rx.consume(n);
            let baud = self.baud;
            let latency = self.usb_latency;
            let pending = &mut self.pending;
            let mut at = self.line_free;
            respond(
                &mut self.chain,
                &packet[..n],
                self.injector.as_mut(),
                &mut self.out[..],
                &mut self.replies,
                |delay, b| {
                    at += delay;
                    for &byte in b {
                        at += wire_time(1, baud);
                        pending.push_back((at + latency, byte));
                    }
                },
            );
            self.line_free = at;
        }
        Ok(())
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        self.clock = self.wall_now();
        let deadline = self.clock + timeout;
        let first = match self.pending.front() {
            Some(&(first, _)) if first <= deadline => first,
            _ => {
                self.wait_until(deadline);
                self.clock = deadline;
                return Ok(0);
            }
        };
        self.clock = self.clock.max(first);
        // Everything that has arrived by now (a reply's bytes come together).
        let mut n = 0;
        while n < buf.len() {
            match self.pending.front() {
                Some(&(t, b)) if t <= self.clock || (n > 0 && t <= self.clock + wire_time(64, self.baud)) => {
                    self.clock = self.clock.max(t);
                    buf[n] = b;
                    n += 1;
                    self.pending.pop_front();
                }
                _ => break,
            }
        }
        // In real time the host sees them only when they have come.
        self.wait_until(self.clock);
        self.catch_up();
        Ok(n)
    }

    fn now(&self) -> Duration {
        self.wall_now()
    }

    fn baud(&self) -> u32 {
        self.baud
    }
}

/// A servo's torque switched on or off by an instruction, as the serving thread saw it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TorqueEvent {
    /// When the instruction was handled.
    pub at: Instant,
    /// The servo.
    pub id: u8,
    /// Torque on after it.
    pub on: bool,
}

/// A chain served on a pseudo-terminal by a thread, in real time: the servos move with the
/// wall clock, replies wait their return delay. Clients open [`PtyChain::path`].
pub struct PtyChain {
    path: String,
    chain: Arc<Mutex<Chain>>,
    torque_log: Arc<Mutex<Vec<TorqueEvent>>>,
    injector: Arc<Mutex<Option<FaultInjector>>>,
    stop: Arc<AtomicBool>,
    /// Whether servos at another baud than the client's port hear nothing.
    baud_checked: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    _client_end: serialport::TTYPort,
}

impl std::fmt::Debug for PtyChain {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PtyChain")
            .field("path", &self.path)
            .finish_non_exhaustive()
    }
}

/// How a served line keeps time (the budget planner's model, `crate::budget`): every byte takes
/// 10 bits at the baud rate; the line is half duplex, so an instruction and its replies follow
/// one another; each reply waits its servo's Return Delay Time; the host sees a reply when the
/// USB adapter's latency timer flushes it after its last byte.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LineTiming {
    /// Bit/s.
    pub baud: u32,
    /// The adapter's latency timer.
    pub usb_latency: Duration,
    /// `SCHED_FIFO` priority of the serving thread, which stands for hardware that keeps its
    /// own time (`None`: normal priority; refused, it runs at normal priority all the same).
    pub priority: Option<i32>,
}

impl LineTiming {
    /// The timing of `bus` (its baud and latency timer), served at normal priority.
    #[must_use]
    pub fn of(bus: &crate::profile::BusConfig) -> LineTiming {
        LineTiming {
            baud: bus.baud,
            usb_latency: Duration::from_micros(u64::from(bus.usb_latency_us)),
            priority: None,
        }
    }

    /// The same, the serving thread at `SCHED_FIFO` `priority` when given.
    #[must_use]
    pub fn at_priority(mut self, priority: Option<i32>) -> LineTiming {
        self.priority = priority;
        self
    }
}

impl PtyChain {
    /// Serves `chain` on a new pseudo-terminal, with optional fault injection; replies go out
    /// as soon as they are made (no line time).
    ///
    /// # Errors
    /// When no pseudo-terminal can be opened.
    pub fn serve(chain: Chain, injector: Option<FaultInjector>) -> io::Result<PtyChain> {
        PtyChain::serve_with(chain, ServoMotion, injector)
    }

    /// Serves `chain` on a new pseudo-terminal keeping line time: a reply reaches the client
    /// when it would on a real bus of `timing`.
    ///
    /// # Errors
    /// When no pseudo-terminal can be opened.
    pub fn serve_timed(chain: Chain, timing: LineTiming) -> io::Result<PtyChain> {
        PtyChain::spawn(chain, ServoMotion, None, Some(timing))
    }

    /// Serves `chain` on a new pseudo-terminal, its servos moved by `plant` on the serving
    /// thread.
    ///
    /// # Errors
    /// When no pseudo-terminal can be opened.
    pub fn serve_with<P: Plant + Send + 'static>(
        chain: Chain,
        plant: P,
        injector: Option<FaultInjector>,
    ) -> io::Result<PtyChain> {
        PtyChain::spawn(chain, plant, injector, None)
    }

    /// Serves `chain`, moved by `plant`, keeping line time ([`PtyChain::serve_timed`]).
    ///
    /// # Errors
    /// When no pseudo-terminal can be opened.
    pub fn serve_timed_with<P: Plant + Send + 'static>(
        chain: Chain,
        plant: P,
        timing: LineTiming,
    ) -> io::Result<PtyChain> {
        PtyChain::spawn(chain, plant, None, Some(timing))
    }

    fn spawn<P: Plant + Send + 'static>(
        chain: Chain,
        mut plant: P,
        injector: Option<FaultInjector>,
        timing: Option<LineTiming>,
    ) -> io::Result<PtyChain> {
        let (mut device_end, client_end) = serialport::TTYPort::pair().map_err(io::Error::other)?;
        close_on_exec(&device_end)?;
        close_on_exec(&client_end)?;
        let path = serialport::SerialPort::name(&client_end)
            .ok_or_else(|| io::Error::other("pseudo-terminal without a name"))?;
        serialport::SerialPort::set_timeout(&mut device_end, Duration::from_millis(1))
            .map_err(io::Error::other)?;
        let chain = Arc::new(Mutex::new(chain));
        let injector = Arc::new(Mutex::new(injector));
        let torque_log = Arc::new(Mutex::new(Vec::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let baud_checked = Arc::new(AtomicBool::new(false));
        let thread = {
            let baud_checked = Arc::clone(&baud_checked);
            let chain = Arc::clone(&chain);
            let injector = Arc::clone(&injector);
            let log = Arc::clone(&torque_log);
            let stop = Arc::clone(&stop);
            std::thread::Builder::new()
                .name("virtual-chain".into())
                .spawn(move || {
                    if let Some(p) = timing.and_then(|t| t.priority) {
                        // Best effort: a refusal leaves the thread at normal priority.
                        let _ = crate::rt::RealTime {
                            priority: Some(p),
                            ..Default::default()
                        }
                        .apply();
                    }
                    serve_loop(
                        &mut device_end,
                        &chain,
                        &mut plant,
                        (&stop, &baud_checked),
                        &injector,
                        &log,
                        timing,
                    );
                })?
        };
        Ok(PtyChain {
            path,
            chain,
            torque_log,
            injector,
            stop,
            baud_checked,
            thread: Some(thread),
            _client_end: client_end,
        })
    }

    /// From now on, servos whose Baud Rate register is not the baud the client set on its
    /// port hear nothing, as on a real bus (by default every servo hears every client).
    pub fn keep_to_the_line_baud(&self) {
        self.baud_checked.store(true, Ordering::Relaxed);
    }

    /// The device path clients open.
    #[must_use]
    pub fn path(&self) -> &str {
        &self.path
    }

    /// The fault injector (locked; keep the guard short).
    pub fn injector(&self) -> MutexGuard<'_, Option<FaultInjector>> {
        self.injector
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Every torque switch the served instructions made, in order (the chain's own record of
    /// when each servo was turned on and off).
    #[must_use]
    pub fn torque_log(&self) -> Vec<TorqueEvent> {
        self.torque_log
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
    }

    /// The chain (locked; keep the guard short).
    ///
    /// # Panics
    /// If the serving thread panicked while holding the lock.
    pub fn chain(&self) -> MutexGuard<'_, Chain> {
        self.chain
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

impl Drop for PtyChain {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Keeps a pseudo-terminal's descriptor out of child processes (as std does for every file it
/// opens): a child holding the device end would keep the line up after the chain closed it.
/// `serialport` opens without the flag, so a child that another thread starts between the open
/// and this call can still inherit it.
#[allow(unsafe_code)]
fn close_on_exec(port: &serialport::TTYPort) -> io::Result<()> {
    use std::os::fd::AsRawFd;
    let fd = port.as_raw_fd();
    // SAFETY: fcntl on a descriptor this value owns, with integer arguments only.
    let flags = unsafe { libc::fcntl(fd, libc::F_GETFD) };
    if flags < 0 || unsafe { libc::fcntl(fd, libc::F_SETFD, flags | libc::FD_CLOEXEC) } < 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(())
}

fn serve_loop(
    port: &mut serialport::TTYPort,
    chain: &Mutex<Chain>,
    plant: &mut impl Plant,
    (stop, baud_checked): (&AtomicBool, &AtomicBool),
    injector: &Mutex<Option<FaultInjector>>,
    torque_log: &Mutex<Vec<TorqueEvent>>,
    timing: Option<LineTiming>,
) {
    let mut rx = Receiver::default();
    let mut out = vec![0u8; 8 * MAX_PACKET];
    let mut replies = Replies::new();
    let mut buf = [0u8; 512];
    let mut last = Instant::now();
    // With line time: when the wire is next free, and each packet's replies with the moment
    // the host may see them.
    let mut line_free = Instant::now();
    let mut timed: Vec<(Instant, Vec<u8>)> = Vec::new();
    while !stop.load(Ordering::Relaxed) {
        match port.read(&mut buf) {
            Ok(n) => rx.push(&buf[..n]),
            Err(e) if e.kind() == io::ErrorKind::TimedOut || e.kind() == io::ErrorKind::Interrupted => {}
            Err(_) => std::thread::sleep(Duration::from_millis(1)),
        }
        // When the bytes were seen: an instruction's wire time counts from here, not from
        // after the servos were stepped.
        let now = Instant::now();
        let mut chain = chain.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        plant.advance(&mut chain, (now - last).as_secs_f64());
        last = now;
        // Chunks without a pause between them go out in one write, as one burst.
        let mut sends: Vec<(Duration, Vec<u8>)> = Vec::new();
        let mut push = |d: Duration, b: &[u8]| match sends.last_mut() {
            Some(last) if d < Duration::from_micros(50) => last.1.extend_from_slice(b),
            _ => sends.push((d, b.to_vec())),
        };
        let mut inj = injector.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if baud_checked.load(Ordering::Relaxed) && rx.pending() > 0 {
            // The pseudo-terminal's two ends share one setting: the client's baud.
            chain.set_line_baud(serialport::SerialPort::baud_rate(port).ok());
        }
        while let Received::Packet(raw) = rx.next_packet() {
            let n = raw.len();
            let packet = raw.to_vec();
            rx.consume(n);
            let before: heapless::Vec<bool, MAX_SERVOS> =
                chain.servos().iter().map(|s| s.torque_on()).collect();
            match timing {
                None => respond(
                    &mut chain,
                    &packet,
                    inj.as_mut(),
                    &mut out,
                    &mut replies,
                    &mut push,
                ),
                Some(t) => {
                    // The instruction on the wire after whatever was on it, then each reply
                    // after its return delay; each reaches the host a latency timer after its
                    // last byte (a long burst trickles in as it comes).
                    let wire = |bytes: usize| wire_time(bytes, t.baud);
                    let mut at = line_free.max(now) + wire(n);
                    respond(
                        &mut chain,
                        &packet,
                        inj.as_mut(),
                        &mut out,
                        &mut replies,
                        |d, b| {
                            at += d + wire(b.len());
                            timed.push((at + t.usb_latency, b.to_vec()));
                        },
                    );
                    line_free = at;
                }
            }
            let at = Instant::now();
            for (s, was) in chain.servos().iter().zip(before) {
                if s.torque_on() != was {
                    torque_log
                        .lock()
                        .unwrap_or_else(std::sync::PoisonError::into_inner)
                        .push(TorqueEvent {
                            at,
                            id: s.id(),
                            on: s.torque_on(),
                        });
                }
            }
        }
        drop(inj);
        drop(chain);
        for (delay, bytes) in sends {
            if delay >= Duration::from_micros(50) {
                std::thread::sleep(delay);
            }
            let _ = port.write_all(&bytes);
        }
        for (due, bytes) in timed.drain(..) {
            sleep_until(due);
            let _ = port.write_all(&bytes);
        }
        let _ = port.flush();
    }
}

/// Sleeps until `due`, spinning the last 200 µs (a sleep wakes 50–100 µs late).
fn sleep_until(due: Instant) {
    let spin = Duration::from_micros(200);
    if let Some(left) = due.checked_duration_since(Instant::now()) {
        if left > spin {
            std::thread::sleep(left - spin);
        }
    }
    while Instant::now() < due {
        std::hint::spin_loop();
    }
}

/// A virtual chain in virtual time as both the loop's bus and its clock: bus transactions take
/// their wire time, waiting for a deadline lets the servos move until then. Clone the handle to
/// pass it as both; deterministic, no threads.
#[derive(Debug)]
pub struct VirtualRig<P: Plant = ServoMotion>(
    std::rc::Rc<std::cell::RefCell<super::packet::PacketBus<InProcess<P>>>>,
);

impl<P: Plant> Clone for VirtualRig<P> {
    fn clone(&self) -> Self {
        VirtualRig(std::rc::Rc::clone(&self.0))
    }
}

impl VirtualRig {
    /// A virtual rig of `chain` at `baud`, replies waited for up to `timeout`.
    #[must_use]
    pub fn new(chain: Chain, baud: u32, timeout: Duration) -> VirtualRig {
        VirtualRig::with_plant(chain, ServoMotion, baud, timeout)
    }
}

impl<P: Plant> VirtualRig<P> {
    /// A virtual rig of `chain` moved by `plant`, at `baud`, replies waited for up to `timeout`.
    #[must_use]
    pub fn with_plant(chain: Chain, plant: P, baud: u32, timeout: Duration) -> VirtualRig<P> {
        VirtualRig(std::rc::Rc::new(std::cell::RefCell::new(
            super::packet::PacketBus::new(InProcess::with_plant(chain, plant, baud), timeout),
        )))
    }

    /// The same with the USB adapter's latency timer ([`InProcess::with_usb_latency`]).
    #[must_use]
    pub fn with_usb_latency(self, latency: Duration) -> VirtualRig<P> {
        self.with(|t| t.usb_latency = latency);
        self
    }

    /// A virtual rig keeping the line time of `bus` (baud, the adapter's latency), replies
    /// waited for as the loop's bus does ([`super::reply_margin`]).
    #[must_use]
    pub fn keeping_time_of(chain: Chain, plant: P, bus: &crate::profile::BusConfig) -> VirtualRig<P> {
        let margin = super::reply_margin(bus, chain.servos().len());
        VirtualRig::with_plant(chain, plant, bus.baud, margin)
            .with_usb_latency(Duration::from_micros(u64::from(bus.usb_latency_us)))
    }

    /// Runs `f` on the transport (the chain, the plant, the injector, the clock).
    pub fn with<R>(&self, f: impl FnOnce(&mut InProcess<P>) -> R) -> R {
        f(self.0.borrow_mut().link_mut())
    }
}

impl<P: Plant> super::ServoBus for VirtualRig<P> {
    fn ping(&mut self, id: u8) -> Result<super::PingInfo, super::BusError> {
        self.0.borrow_mut().ping(id)
    }
    fn scan(&mut self) -> Result<Vec<super::PingInfo>, super::BusError> {
        self.0.borrow_mut().scan()
    }
    fn read(&mut self, id: u8, address: u16, out: &mut [u8]) -> Result<(), super::BusError> {
        self.0.borrow_mut().read(id, address, out)
    }
    fn write(&mut self, id: u8, address: u16, data: &[u8]) -> Result<(), super::BusError> {
        self.0.borrow_mut().write(id, address, data)
    }
    fn sync_write(&mut self, address: u16, len: u16, ids: &[u8], data: &[u8]) -> Result<(), super::BusError> {
        self.0.borrow_mut().sync_write(address, len, ids, data)
    }
    fn sync_read(
        &mut self,
        address: u16,
        len: u16,
        ids: &[u8],
        out: &mut [u8],
    ) -> Result<(), super::BusError> {
        self.0.borrow_mut().sync_read(address, len, ids, out)
    }
    fn reboot(&mut self, id: u8) -> Result<(), super::BusError> {
        self.0.borrow_mut().reboot(id)
    }
    fn read_positions(&mut self, ids: &[u8], out: &mut [i32]) -> Result<(), super::BusError> {
        self.0.borrow_mut().read_positions(ids, out)
    }
    fn request_read(&mut self, id: u8, address: u16, len: u16) -> Result<(), super::BusError> {
        self.0.borrow_mut().request_read(id, address, len)
    }
    fn collect_read(&mut self, id: u8, address: u16, out: &mut [u8]) -> Result<(), super::BusError> {
        self.0.borrow_mut().collect_read(id, address, out)
    }
    fn request_positions(&mut self, ids: &[u8]) -> Result<(), super::BusError> {
        self.0.borrow_mut().request_positions(ids)
    }
    fn collect_positions(&mut self, ids: &[u8], out: &mut [i32]) -> Result<(), super::BusError> {
        self.0.borrow_mut().collect_positions(ids, out)
    }
    fn merge_into_reads(&mut self, id: u8, address: u16, len: u16) -> bool {
        self.0.borrow_mut().merge_into_reads(id, address, len)
    }
    fn take_merged(&mut self, out: &mut [u8]) -> Option<bool> {
        self.0.borrow_mut().take_merged(out)
    }
    fn take_alert(&mut self) -> Option<u8> {
        self.0.borrow_mut().take_alert()
    }
}

impl<P: Plant> crate::schedule::Clock for VirtualRig<P> {
    fn now_ns(&mut self) -> u64 {
        u64::try_from(self.0.borrow().link().now().as_nanos()).unwrap_or(u64::MAX)
    }

    fn wait_until(&mut self, deadline_ns: u64) {
        let now = self.now_ns();
        if deadline_ns > now {
            self.with(|t| t.advance(Duration::from_nanos(deadline_ns - now)));
        }
    }
}
