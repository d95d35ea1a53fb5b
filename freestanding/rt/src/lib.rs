//! Runtime for the freestanding (`#![no_std] #![no_main]`) binaries, one API on every platform.
//!
//! A binary calls [`entry!`] with its main function (`fn() -> i32`); the platform's start-up
//! code calls it and exits with its return value. Bytes go in through [`read`] (descriptor 0)
//! and out through [`write`] (1: the data stream, 2: diagnostics). The board layers:
//!
//! - `linux` (x86_64): `_start`, raw system calls, the C memory functions; descriptors are the
//!   process's. The tests' stand-in for a device.
//! - `mps2` (Arm, thumbv7em-none-eabihf): the vector table, a reset handler that enables the
//!   FPU and paints the stack, the board's first UART as the data stream (both directions; a
//!   UART has no end of input, so [`read`] never returns 0), semihosting for diagnostics and the
//!   exit code.
//!
//! What does not depend on the platform is here: [`read_exact`], [`write_all`],
//! [`ZeroedStatic`], the panic handler, and the measurement marks ([`mark_begin`],
//! [`mark_end`]).
#![no_std]

#[cfg(target_arch = "x86_64")]
mod linux;
#[cfg(target_arch = "x86_64")]
pub use linux::{exit, read, write};

#[cfg(all(target_arch = "arm", target_os = "none"))]
mod mps2;
#[cfg(all(target_arch = "arm", target_os = "none"))]
pub use mps2::{exit, read, write};

/// Defines the binary's main function for the platform's start-up code:
/// `mpo_rt::entry!(main);` with `fn main() -> i32` (the exit code).
#[macro_export]
macro_rules! entry {
    ($main:path) => {
        #[unsafe(no_mangle)]
        extern "Rust" fn __mpo_rt_main() -> i32 {
            $main()
        }
    };
}

unsafe extern "Rust" {
    /// The binary's main function, defined by [`entry!`].
    fn __mpo_rt_main() -> i32;
}

/// Runs the binary's main function (the board layers' start-up code calls this).
fn run_main() -> i32 {
    // SAFETY: defined by `entry!` in the binary with exactly this signature; a binary without
    // it fails to link.
    unsafe { __mpo_rt_main() }
}

/// Writes all of `bytes` (retrying short writes); false on error.
pub fn write_all(fd: u32, mut bytes: &[u8]) -> bool {
    while !bytes.is_empty() {
        let n = write(fd, bytes);
        if n <= 0 {
            return false;
        }
        bytes = &bytes[n as usize..];
    }
    true
}

/// Fills `buf` completely. `Ok(true)`: filled; `Ok(false)`: clean end of input before the
/// first byte; `Err(())`: an error or end of input in the middle of a record.
pub fn read_exact(fd: u32, buf: &mut [u8]) -> Result<bool, ()> {
    let mut got = 0;
    while got < buf.len() {
        let n = read(fd, &mut buf[got..]);
        if n < 0 || (n == 0 && got > 0) {
            return Err(());
        }
        if n == 0 {
            return Ok(false);
        }
        got += n as usize;
    }
    Ok(true)
}

/// Marks the start of a measured span of work (an inference, an environment step). It does
/// nothing, at the cost of a call and a return: the instruction counter run under QEMU
/// (`scripts/qemu-count`) records its instruction count whenever this function's first
/// instruction executes, and [`mark_end`]'s likewise, so the difference is the span's exact
/// instruction count.
#[inline(never)]
#[unsafe(no_mangle)]
pub extern "C" fn mpo_mark_begin() {
    // A block the optimiser must keep (it may have side effects), so the call stays; one `nop`
    // here and two in `mpo_mark_end`, so the linker cannot fold the two into one address.
    // SAFETY: no-operations.
    unsafe { core::arch::asm!("nop", options(nomem, nostack, preserves_flags)) }
}

/// Marks the end of a measured span (see [`mpo_mark_begin`]).
#[inline(never)]
#[unsafe(no_mangle)]
pub extern "C" fn mpo_mark_end() {
    // SAFETY: no-operations.
    unsafe { core::arch::asm!("nop", "nop", options(nomem, nostack, preserves_flags)) }
}

pub use mpo_mark_begin as mark_begin;
pub use mpo_mark_end as mark_end;

/// A zero-initialised static (it lands in `.bss`), handed out once as `&'static mut T`: how a
/// freestanding binary holds state too big for its stack (the device trainer's learner and
/// replay) without an allocator. `T` must be valid all-zero ([`bytemuck::Zeroable`]).
pub struct ZeroedStatic<T> {
    taken: core::sync::atomic::AtomicBool,
    cell: core::cell::UnsafeCell<core::mem::MaybeUninit<T>>,
}

// SAFETY: the value is reachable only through the one `&'static mut` that `take` hands out.
unsafe impl<T: Send> Sync for ZeroedStatic<T> {}

impl<T: bytemuck::Zeroable> ZeroedStatic<T> {
    /// The all-zero value.
    pub const fn new() -> Self {
        Self {
            taken: core::sync::atomic::AtomicBool::new(false),
            cell: core::cell::UnsafeCell::new(core::mem::MaybeUninit::zeroed()),
        }
    }

    /// The value, the first time; `None` after that.
    pub fn take(&'static self) -> Option<&'static mut T> {
        if self.taken.swap(true, core::sync::atomic::Ordering::AcqRel) {
            return None;
        }
        // SAFETY: all-zero is a valid `T` (`Zeroable`), and the flag makes this the only
        // reference ever created.
        Some(unsafe { (*self.cell.get()).assume_init_mut() })
    }
}

impl<T: bytemuck::Zeroable> Default for ZeroedStatic<T> {
    fn default() -> Self {
        Self::new()
    }
}

/// Exit code of a panic.
pub const EXIT_PANIC: i32 = 101;

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    write(2, b"panic\n");
    exit(EXIT_PANIC)
}

/// Never called with `panic = "abort"`, but precompiled `core` objects may reference it.
#[unsafe(no_mangle)]
pub extern "C" fn rust_eh_personality() {}
