//! Real-time settings of the loop thread: `SCHED_FIFO` priority, CPU affinity, `mlockall`.
//! Each is optional; when the system refuses one (no `CAP_SYS_NICE`, a container), the loop
//! runs without it and the caller prints the one-line warning returned.

/// What to ask of the system for the calling thread.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RealTime {
    /// `SCHED_FIFO` priority (1 … 99).
    pub priority: Option<i32>,
    /// Pin the thread to this CPU.
    pub cpu: Option<usize>,
    /// Lock all present and future pages in memory (no page faults in the loop).
    pub lock_memory: bool,
}

impl RealTime {
    /// Applies the settings to the calling thread; returns a warning for each refused one.
    #[must_use]
    pub fn apply(&self) -> Vec<String> {
        let mut warnings = Vec::new();
        if let Some(p) = self.priority {
            if let Err(e) = set_fifo(p) {
                warnings.push(format!(
                    "warning: SCHED_FIFO priority {p} refused ({e}); running at normal priority (grant CAP_SYS_NICE or an rtprio limit)"
                ));
            }
        }
        if let Some(cpu) = self.cpu {
            if let Err(e) = set_affinity(cpu) {
                warnings.push(format!(
                    "warning: pinning the loop to CPU {cpu} refused ({e}); running unpinned"
                ));
            }
        }
        if self.lock_memory {
            if let Err(e) = lock_memory() {
                warnings.push(format!(
                    "warning: mlockall refused ({e}); memory not locked (raise the memlock limit)"
                ));
            }
        }
        warnings
    }
}

#[cfg(target_os = "linux")]
#[allow(unsafe_code)]
fn set_fifo(priority: i32) -> std::io::Result<()> {
    let param = libc::sched_param {
        sched_priority: priority.clamp(1, 99),
    };
    // SAFETY: `param` is a valid sched_param; pid 0 is the calling thread.
    let r = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

#[cfg(target_os = "linux")]
#[allow(unsafe_code)]
fn set_affinity(cpu: usize) -> std::io::Result<()> {
    if cpu >= libc::CPU_SETSIZE as usize {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "no such CPU",
        ));
    }
    // SAFETY: a zeroed cpu_set_t is the empty set; CPU_SET stays within it (checked above);
    // pid 0 is the calling thread and the size is that of the set passed.
    let r = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(cpu, &mut set);
        libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set)
    };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

#[cfg(target_os = "linux")]
#[allow(unsafe_code)]
fn lock_memory() -> std::io::Result<()> {
    // SAFETY: mlockall takes flags only.
    let r = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

#[cfg(not(target_os = "linux"))]
fn set_fifo(_: i32) -> std::io::Result<()> {
    Err(std::io::Error::other("only on Linux"))
}

#[cfg(not(target_os = "linux"))]
fn set_affinity(_: usize) -> std::io::Result<()> {
    Err(std::io::Error::other("only on Linux"))
}

#[cfg(not(target_os = "linux"))]
fn lock_memory() -> std::io::Result<()> {
    Err(std::io::Error::other("only on Linux"))
}
