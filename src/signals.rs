//! Termination signals as stop requests. SIGINT (Ctrl-C), SIGTERM (`kill`, `systemctl stop`),
//! SIGHUP (the terminal closed) and SIGQUIT (Ctrl-\) each ask the control loop to stop: it
//! eases to rest or holds, then turns torque off; a second signal during the ramp turns torque
//! off at once. Installed once per process; a thread turns each signal into a count.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use signal_hook::consts::{SIGHUP, SIGINT, SIGQUIT, SIGTERM};
use signal_hook::iterator::Signals;

use crate::control::StopRequests;

/// The signals that stop the loop.
pub const STOP_SIGNALS: [i32; 4] = [SIGINT, SIGTERM, SIGHUP, SIGQUIT];

static COUNT: Mutex<Option<Arc<AtomicUsize>>> = Mutex::new(None);

/// Stop requests from [`STOP_SIGNALS`], counted from now. The first call in a process installs
/// the handlers (replacing any disposition inherited, `ignore` included).
///
/// # Errors
/// When the handlers or their thread cannot be set up.
pub fn stop_requests() -> std::io::Result<StopRequests> {
    let mut slot = COUNT.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    if let Some(count) = slot.as_ref() {
        return Ok(StopRequests::counting_from_now(Arc::clone(count)));
    }
    let count = Arc::new(AtomicUsize::new(0));
    let mut signals = Signals::new(STOP_SIGNALS)?;
    let counted = Arc::clone(&count);
    std::thread::Builder::new()
        .name("stop-signals".into())
        .spawn(move || {
            for _ in signals.forever() {
                counted.fetch_add(1, Ordering::SeqCst);
            }
        })?;
    *slot = Some(Arc::clone(&count));
    Ok(StopRequests::counting_from_now(count))
}
