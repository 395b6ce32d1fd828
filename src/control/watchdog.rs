//! The servos' Bus Watchdog after the loop went quiet. A host that stalls (a virtual machine
//! paused, a swap storm, a debugger) longer than the watchdog leaves every servo stopped where it
//! was, refusing goals — and a Sync Write gets no status, so nothing else would tell the loop.
//! Once the bus has been quiet for half the watchdog or more (seen before a tick's write, or, for
//! a stall inside a tick, as the span between two ticks' transactions), the tick reads the Bus
//! Watchdog register of every servo before its write (−1 after an expiry, e-manual) — the first
//! tick does too, start-up having armed the watchdog some time before; when any expired it
//! takes their present positions, clears the expiry (writing 0), holds them there, arms the
//! watchdog again and reads it back. The command stage then starts from those positions at rest
//! and eases back to the input, as at the start of a run: no servo jumps to where the input
//! went while the host was away. The resumed move is not in the fidelity.

use super::Controller;
use crate::bus::{watchdog_units, ServoBus};
use crate::schedule::{Clock, Tick};
use crate::servo::{addr, MAX_SERVOS};

/// What the Bus Watchdog register reads after an expiry (−1 as a byte).
pub const EXPIRED: u8 = 0xFF;

/// When the servos last heard the loop, and whether a check is owed.
#[derive(Debug, Default)]
pub(super) struct QuietWatch {
    /// When the last tick's transactions ended, ns on the loop clock (`None` before the first).
    pub(super) last_sent_ns: Option<u64>,
    /// A check is due at the next tick: a span between ticks' transactions was long enough for
    /// the watchdog to matter, or a check could not finish (a read failed).
    pub(super) owed: bool,
    /// Consecutive checks whose watchdog, armed again, read back otherwise.
    pub(super) rearm_misses: u8,
}

/// Checks in a row that arm a watchdog which reads back otherwise before the loop stops trying
/// until the next quiet spell.
const MAX_REARM_MISSES: u8 = 3;

/// A check made in a tick: its bus time, and the goals that hold the servos where they stopped
/// when any had expired.
pub(super) struct Checked {
    pub(super) bus_ns: u64,
    pub(super) hold: Option<[i32; MAX_SERVOS]>,
}

impl Controller {
    /// After a tick's transactions (at `now_ns`): a stall anywhere since the last tick's — in
    /// this tick too, after its check — shows as a span of half the watchdog or more, and owes
    /// the next tick a check.
    pub(super) fn note_sent(&mut self, now_ns: u64) {
        let watchdog_ms = self.config.bus_watchdog_ms;
        if let (true, Some(t)) = (watchdog_ms > 0, self.quiet.last_sent_ns) {
            let span_ms = now_ns.saturating_sub(t) as f64 * 1e-6;
            self.stats.longest_quiet_ms = self.stats.longest_quiet_ms.max(span_ms);
            if 2.0 * span_ms >= f64::from(watchdog_ms) {
                self.quiet.owed = true;
                self.quiet.rearm_misses = 0;
                self.stats.quiet_spells += 1;
            }
        }
        self.quiet.last_sent_ns = Some(now_ns);
    }

    /// Before the tick's write (at `now_ns`): when the servos have heard nothing for half their
    /// watchdog or more (or a check is owed), reads every servo's Bus Watchdog and recovers the
    /// ones that expired (module docs), easing back to the input when `ease_back` (not in the
    /// ramp at the end, which goes on from where they stopped). `None` when no check was due.
    /// Allocates nothing.
    pub(super) fn check_watchdog(
        &mut self,
        tick: &Tick,
        bus: &mut dyn ServoBus,
        clock: &mut dyn Clock,
        now_ns: u64,
        ease_back: bool,
    ) -> Option<Checked> {
        let watchdog_ms = self.config.bus_watchdog_ms;
        if watchdog_ms == 0 {
            return None;
        }
        let quiet_ns = self.quiet.last_sent_ns.map_or(0, |t| now_ns.saturating_sub(t));
        let quiet_ms = quiet_ns as f64 * 1e-6;
        self.stats.longest_quiet_ms = self.stats.longest_quiet_ms.max(quiet_ms);
        let quiet = 2.0 * quiet_ms >= f64::from(watchdog_ms);
        if !(quiet || self.quiet.owed) {
            return None;
        }
        if quiet {
            // A new quiet spell: a watchdog that would not arm is tried again.
            self.quiet.rearm_misses = 0;
            self.stats.quiet_spells += 1;
        }
        self.stats.watchdog_checks += 1;
        let t0 = clock.now_ns();
        let hold = self.recover_watchdog(tick, bus, watchdog_units(watchdog_ms), ease_back);
        // Its transactions are the servos' latest: the tick's span counts from them.
        let t1 = clock.now_ns();
        self.quiet.last_sent_ns = Some(t1);
        Some(Checked {
            bus_ns: t1.saturating_sub(t0),
            hold,
        })
    }

    /// Reads the watchdogs; when any expired, recovers them and restarts the command stage from
    /// where the servos stand, returning the goals that hold them there; arms any not armed as
    /// the run armed them. A check that could not finish is owed to the next tick.
    fn recover_watchdog(
        &mut self,
        tick: &Tick,
        bus: &mut dyn ServoBus,
        units: u8,
        ease_back: bool,
    ) -> Option<[i32; MAX_SERVOS]> {
        let n = self.ids.len();
        self.quiet.owed = true;
        let mut armed = [0u8; MAX_SERVOS];
        if let Err(e) = bus.sync_read(addr::BUS_WATCHDOG, 1, &self.ids, &mut armed[..n]) {
            self.stats.bus_error(e.kind());
            return None;
        }
        let mut expired: heapless::Vec<u8, MAX_SERVOS> = heapless::Vec::new();
        let mut disarmed: heapless::Vec<u8, MAX_SERVOS> = heapless::Vec::new();
        for (&id, &a) in self.ids.iter().zip(&armed[..n]) {
            let list = if a == EXPIRED { &mut expired } else { &mut disarmed };
            if a != units {
                let _ = list.push(id);
            }
        }
        if expired.is_empty() && disarmed.is_empty() {
            self.quiet.owed = false;
            return None;
        }
        let mut hold = None;
        if !expired.is_empty() {
            // Where they stopped, before anything may move them.
            if let Err(e) = bus.read_positions(&self.ids, &mut self.reads.read_buf) {
                self.stats.bus_error(e.kind());
                return None;
            }
            self.stats.watchdog_expiries += 1;
            self.reads.present.copy_from_slice(&self.reads.read_buf);
            let mut goals = [0i32; MAX_SERVOS];
            goals[..n].copy_from_slice(&self.reads.present);
            // Cleared, the servos take goals again: the first is where they stand.
            let zeros = [0u8; MAX_SERVOS];
            let cleared = bus
                .sync_write(addr::BUS_WATCHDOG, 1, &expired, &zeros[..expired.len()])
                .and_then(|()| bus.write_goals(&self.ids, &goals[..n]));
            if let Err(e) = cleared {
                self.stats.bus_error(e.kind());
            }
            self.restart_from_present(tick, ease_back);
            hold = Some(goals);
        }
        let mut rearm = expired;
        rearm.extend(disarmed);
        let units_each = [units; MAX_SERVOS];
        let rearmed = bus
            .sync_write(addr::BUS_WATCHDOG, 1, &rearm, &units_each[..rearm.len()])
            .and_then(|()| bus.sync_read(addr::BUS_WATCHDOG, 1, &self.ids, &mut armed[..n]));
        match rearmed {
            Ok(()) if armed[..n].iter().all(|&a| a == units) => {
                self.quiet.owed = false;
                self.quiet.rearm_misses = 0;
            }
            // Read back otherwise: armed again at the next ticks, a few times at most (a servo
            // that never takes it would cost every tick a check).
            Ok(()) => {
                self.quiet.rearm_misses = self.quiet.rearm_misses.saturating_add(1);
                self.quiet.owed = self.quiet.rearm_misses < MAX_REARM_MISSES;
            }
            Err(e) => self.stats.bus_error(e.kind()),
        }
        hold
    }

    /// The command stage from the present positions at rest, and — while input flows (not in
    /// the ramp at the end) — an ease from them back to it, as long as the eased move to the
    /// input's pose at a quarter of the servos' speed takes (as the start move is sized); not in
    /// the fidelity.
    fn restart_from_present(&mut self, tick: &Tick, ease_back: bool) {
        self.stage.start_from(&self.rig, &self.reads.present);
        self.reads.have_previous = false;
        if let Some(la) = &mut self.lookahead {
            la.forget_plans();
        }
        if !(self.have_input && ease_back) {
            return;
        }
        for ((from, s), p) in self
            .ease
            .from
            .iter_mut()
            .zip(&self.rig.servos)
            .zip(&self.reads.present)
        {
            *from = s.ticks_to_angle(f64::from(*p));
        }
        let ticks = self.eased_move_ticks().map_or(0, |(t, _)| t).max(1);
        self.ease.ticks = ticks;
        self.ease.done = 0;
        self.ease.start_ns = Some(tick.deadline_ns + self.period_ns);
        self.stats.resumed_s += ticks as f64 * self.period_ns as f64 * 1e-9;
    }
}
