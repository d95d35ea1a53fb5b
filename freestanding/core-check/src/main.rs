//! Freestanding check binary: `_start` -> run the core's self-check -> print -> exit.
//!
//! Output (stdout): `selfcheck <seed> <steps> <hex>`, `learner <seed> <updates> <hex>` and
//! `forward <seed> <hex>`, one per line.
#![no_std]
#![no_main]

#[cfg(feature = "use-alloc")]
extern crate alloc;
#[cfg(feature = "use-std")]
extern crate std;

use mpo_core::bytemuck::Zeroable;
use mpo_core::selfcheck::{SelfCheck, forward_checksum};

const SEED: u64 = 42;
const STEPS: usize = 200;
const UPDATES: usize = 6;

mpo_rt::entry!(main);

fn main() -> i32 {
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
    line.push(b"\nlearner ");
    line.push_dec(SEED);
    line.push(b" ");
    line.push_dec(UPDATES as u64);
    line.push(b" ");
    line.push_hex(check.learner(SEED, UPDATES));
    line.push(b"\nforward ");
    line.push_dec(SEED);
    line.push(b" ");
    line.push_hex(forward_checksum(SEED));
    line.push(b"\n");
    if mpo_rt::write_all(1, line.as_bytes()) {
        0
    } else {
        1
    }
}

/// A fixed-capacity output buffer (no allocator here).
struct Line {
    buf: [u8; 256],
    len: usize,
}

impl Line {
    fn new() -> Self {
        Self {
            buf: [0; 256],
            len: 0,
        }
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
