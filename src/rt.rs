//! Real-time settings of the loop thread: `SCHED_FIFO` priority, CPU affinity, `mlockall`;
//! its stack and the program's code mapped before the loop, and its page faults counted.
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

/// Bytes of the calling thread's stack that [`prefault`] writes: more than the loop's deepest
/// call (its solves, the fidelity's messages, the telemetry) uses.
pub const STACK_PREFAULT_BYTES: usize = 256 * 1024;

/// Maps now what the loop's first use of it would otherwise fault in, one page at a time, seconds
/// into a run (the first solve, the first fidelity record, the first health check): the
/// calling thread's stack ([`STACK_PREFAULT_BYTES`] written) and the program's code (every
/// executable mapping of a file, by `MADV_POPULATE_READ`; kernels before 5.14 refuse it, and
/// the code is then mapped as it first runs). Call it on the loop thread before the loop.
pub fn prefault() {
    prefault_stack();
    prefault_code();
}

#[inline(never)]
fn prefault_stack() {
    let mut page = [0u8; STACK_PREFAULT_BYTES];
    for b in page.iter_mut().step_by(4096) {
        *b = 1;
    }
    std::hint::black_box(&mut page);
}

#[cfg(target_os = "linux")]
#[allow(unsafe_code)]
fn prefault_code() {
    let Ok(maps) = std::fs::read_to_string("/proc/self/maps") else {
        return;
    };
    for (start, end) in maps.lines().filter_map(executable_file_mapping) {
        // SAFETY: the range is one of this process's mappings as the kernel lists it;
        // MADV_POPULATE_READ only fills page tables and changes no memory.
        let _ = unsafe { libc::madvise(start as *mut libc::c_void, end - start, libc::MADV_POPULATE_READ) };
    }
}

#[cfg(not(target_os = "linux"))]
fn prefault_code() {}

/// A `/proc/self/maps` line's address range when it maps a file executable.
fn executable_file_mapping(line: &str) -> Option<(usize, usize)> {
    let mut fields = line.split_whitespace();
    let (range, perms) = (fields.next()?, fields.next()?);
    let path = fields.nth(3)?;
    if perms.as_bytes().get(2) != Some(&b'x') || !path.starts_with('/') {
        return None;
    }
    let (start, end) = range.split_once('-')?;
    let start = usize::from_str_radix(start, 16).ok()?;
    let end = usize::from_str_radix(end, 16).ok()?;
    (end > start).then_some((start, end))
}

/// The calling thread's minor page faults so far (`getrusage(RUSAGE_THREAD)`); `None` where
/// the system does not count them per thread.
#[cfg(target_os = "linux")]
#[allow(unsafe_code)]
#[must_use]
pub fn thread_minor_faults() -> Option<u64> {
    let mut usage = std::mem::MaybeUninit::<libc::rusage>::zeroed();
    // SAFETY: getrusage writes one `rusage` into the buffer it is given.
    let r = unsafe { libc::getrusage(libc::RUSAGE_THREAD, usage.as_mut_ptr()) };
    // SAFETY: a zeroed `rusage` is valid, and a successful call filled it.
    (r == 0).then(|| u64::try_from(unsafe { usage.assume_init() }.ru_minflt).unwrap_or(0))
}

/// The calling thread's minor page faults so far; `None` where the system does not count them
/// per thread.
#[cfg(not(target_os = "linux"))]
#[must_use]
pub fn thread_minor_faults() -> Option<u64> {
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_executable_mappings_of_files_are_taken() {
        let text = "5604f5400000-5604f5a00000 r-xp 00200000 fd:01 1234 /usr/bin/marionette";
        assert_eq!(
            executable_file_mapping(text),
            Some((0x5604_f540_0000, 0x5604_f5a0_0000))
        );
        for other in [
            "5604f5a00000-5604f5b00000 r--p 00800000 fd:01 1234 /usr/bin/marionette",
            "7ffd1000-7ffd2000 r-xp 00000000 00:00 0 [vdso]",
            "7f0000000000-7f0000100000 rw-p 00000000 00:00 0",
            "garbage",
        ] {
            assert_eq!(executable_file_mapping(other), None, "{other}");
        }
    }

    /// Writes `bytes` of the stack below the caller.
    #[inline(never)]
    fn use_stack(bytes: usize) -> u8 {
        let mut block = [0u8; 192 * 1024];
        for b in block[..bytes.min(192 * 1024)].iter_mut().step_by(512) {
            *b = 3;
        }
        std::hint::black_box(&mut block)[100]
    }

    #[test]
    fn after_prefault_the_loops_stack_takes_no_page_fault() {
        let faults = std::thread::spawn(|| {
            prefault();
            let before = thread_minor_faults();
            let x = use_stack(192 * 1024);
            thread_minor_faults().zip(before).map(|(a, b)| (a - b, x))
        })
        .join()
        .unwrap();
        if let Some((n, _)) = faults {
            assert_eq!(n, 0);
        }
    }
}
