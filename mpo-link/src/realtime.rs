//! Real-time scheduling for a paced control loop.
//!
//! Under the default scheduler a 1 kHz loop shares the cores with everything else: on a busy
//! machine a wake-up can wait for a whole scheduler slice (milliseconds). `SCHED_FIFO` lets the
//! plant and the controller preempt ordinary processes; locking memory keeps page faults out of
//! the loop. Both need privileges (root or `CAP_SYS_NICE` / `CAP_IPC_LOCK`); the error says so.
//! Never combine with busy-polling: a spinning FIFO thread starves the core.

/// Switches the calling thread to `SCHED_FIFO` at `priority` (1-99) and locks all current and
/// future memory.
pub fn enter(priority: i32) -> Result<(), String> {
    // SAFETY: plain syscalls with a fully initialised argument.
    unsafe {
        let param = libc::sched_param {
            sched_priority: priority,
        };
        if libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) != 0 {
            return Err(format!(
                "SCHED_FIFO {priority}: {}",
                std::io::Error::last_os_error()
            ));
        }
        if libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) != 0 {
            return Err(format!("mlockall: {}", std::io::Error::last_os_error()));
        }
    }
    Ok(())
}

/// Sets this thread's timer slack to 1 ns: by default Linux may delay a timed sleep by up to
/// 50 us to batch wake-ups, which shows up directly as jitter in a paced loop.
pub fn tight_timer_slack() {
    // SAFETY: PR_SET_TIMERSLACK takes a plain integer.
    unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong) };
}

/// Sleeps until `t_ns` on `CLOCK_MONOTONIC` (absolute, so a paced loop's lateness does not
/// accumulate). A signal ends the sleep early; callers check their stop flag.
pub fn sleep_until(t_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (t_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (t_ns % 1_000_000_000) as libc::c_long,
    };
    // SAFETY: a valid timespec; no remainder is asked for.
    unsafe {
        libc::clock_nanosleep(
            libc::CLOCK_MONOTONIC,
            libc::TIMER_ABSTIME,
            &ts,
            core::ptr::null_mut(),
        )
    };
}
