//! Freestanding check binary: `_start` -> run the core's self-check -> print -> exit.
//!
//! Output (stdout): `selfcheck <seed> <steps> <hex>` and `forward <seed> <hex>`, one per line.
#![no_std]
#![no_main]

#[cfg(feature = "use-alloc")]
extern crate alloc;
#[cfg(feature = "use-std")]
extern crate std;

use core::arch::global_asm;
use mpo_core::bytemuck::Zeroable;
use mpo_core::selfcheck::{SelfCheck, forward_checksum};

const SEED: u64 = 42;
const STEPS: usize = 200;

// The kernel enters `_start` with the stack pointer 16-byte aligned and pointing at argc;
// the System V ABI wants it 16-byte aligned *before* a call, so clear the frame pointer,
// realign and call into Rust.
global_asm!(
    ".globl _start",
    "_start:",
    "xor ebp, ebp",
    "and rsp, -16",
    "call {entry}",
    "ud2",
    entry = sym entry,
);

extern "C" fn entry() -> ! {
    #[cfg(feature = "use-alloc")]
    core::hint::black_box(alloc::boxed::Box::new(1u8));
    let mut check = SelfCheck::zeroed();
    let fp = check.run(SEED, STEPS);
    let mut line = Line::new();
    line.push(b"selfcheck ");
    line.push_dec(SEED);
    line.push(b" ");
    line.push_dec(STEPS as u64);
    line.push(b" ");
    line.push_hex(fp);
    line.push(b"\nforward ");
    line.push_dec(SEED);
    line.push(b" ");
    line.push_hex(forward_checksum(SEED));
    line.push(b"\n");
    write(1, line.as_bytes());
    exit(0)
}

/// A fixed-capacity output buffer (no allocator here).
struct Line {
    buf: [u8; 256],
    len: usize,
}

impl Line {
    fn new() -> Self {
        Self { buf: [0; 256], len: 0 }
    }
    fn push(&mut self, s: &[u8]) {
        for &b in s {
            if self.len < self.buf.len() {
                self.buf[self.len] = b;
                self.len += 1;
            }
        }
    }
    fn push_hex(&mut self, v: u64) {
        for i in (0..16).rev() {
            let d = ((v >> (4 * i)) & 0xf) as u8;
            self.push(&[if d < 10 { b'0' + d } else { b'a' + d - 10 }]);
        }
    }
    fn push_dec(&mut self, mut v: u64) {
        let mut digits = [0u8; 20];
        let mut n = 0;
        loop {
            digits[n] = b'0' + (v % 10) as u8;
            n += 1;
            v /= 10;
            if v == 0 {
                break;
            }
        }
        for i in (0..n).rev() {
            self.push(&[digits[i]]);
        }
    }
    fn as_bytes(&self) -> &[u8] {
        &self.buf[..self.len]
    }
}

fn write(fd: u64, bytes: &[u8]) {
    // SAFETY: write(2) with a valid pointer and length; rcx and r11 are clobbered by syscall.
    unsafe {
        core::arch::asm!(
            "syscall",
            inlateout("rax") 1u64 => _,
            in("rdi") fd,
            in("rsi") bytes.as_ptr(),
            in("rdx") bytes.len(),
            lateout("rcx") _,
            lateout("r11") _,
            options(nostack),
        );
    }
}

fn exit(code: u64) -> ! {
    // SAFETY: exit_group(2) does not return.
    unsafe {
        core::arch::asm!("syscall", in("rax") 231u64, in("rdi") code, options(noreturn, nostack));
    }
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    write(2, b"core-check: panic\n");
    exit(101)
}

/// Never called with `panic = "abort"`, but some precompiled core objects reference it.
#[unsafe(no_mangle)]
pub extern "C" fn rust_eh_personality() {}

// The compiler lowers copies and fills to these C symbols; without libc we provide them.
// `rep movsb`/`rep stosb` in assembly, because a Rust loop here could itself be lowered back
// into a call to the function being defined.

/// # Safety
/// C `memcpy` contract.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn memcpy(dst: *mut u8, src: *const u8, n: usize) -> *mut u8 {
    // SAFETY: caller guarantees non-overlapping valid ranges of n bytes.
    unsafe {
        core::arch::asm!("rep movsb", inout("rcx") n => _, inout("rdi") dst => _, inout("rsi") src => _, options(nostack, preserves_flags));
    }
    dst
}

/// # Safety
/// C `memmove` contract.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn memmove(dst: *mut u8, src: *const u8, n: usize) -> *mut u8 {
    if (dst as usize) <= (src as usize) || (dst as usize) >= (src as usize) + n {
        // SAFETY: forward copy is safe when dst precedes src or the ranges are disjoint.
        unsafe { memcpy(dst, src, n) }
    } else {
        // SAFETY: backward copy with the direction flag set, then cleared again.
        unsafe {
            core::arch::asm!(
                "std", "rep movsb", "cld",
                inout("rcx") n => _,
                inout("rdi") dst.add(n - 1) => _,
                inout("rsi") src.add(n - 1) => _,
                options(nostack),
            );
        }
        dst
    }
}

/// # Safety
/// C `memset` contract.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn memset(dst: *mut u8, c: i32, n: usize) -> *mut u8 {
    // SAFETY: caller guarantees a valid range of n bytes.
    unsafe {
        core::arch::asm!("rep stosb", inout("rcx") n => _, inout("rdi") dst => _, in("al") c as u8, options(nostack, preserves_flags));
    }
    dst
}

/// # Safety
/// C `memcmp` contract.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn memcmp(a: *const u8, b: *const u8, n: usize) -> i32 {
    let mut i = 0;
    while i < n {
        // SAFETY: caller guarantees valid ranges of n bytes.
        let (x, y) = unsafe { (core::ptr::read_volatile(a.add(i)), core::ptr::read_volatile(b.add(i))) };
        if x != y {
            return x as i32 - y as i32;
        }
        i += 1;
    }
    0
}

/// # Safety
/// C `bcmp` contract.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn bcmp(a: *const u8, b: *const u8, n: usize) -> i32 {
    // SAFETY: same contract as memcmp.
    unsafe { memcmp(a, b, n) }
}
