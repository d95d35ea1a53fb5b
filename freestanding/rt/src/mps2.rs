//! The board layer for Arm's MPS2 with the AN386 image: a Cortex-M4F (single-precision FPU with
//! fused multiply-add), flash-like memory at 0x0, RAM at 0x2000_0000 (`mps2-an386.ld`), as
//! QEMU's `mps2-an386` machine models it.
//!
//! - Reset: enables the FPU (before any floating-point instruction could run), copies `.data`,
//!   zeroes `.bss`, paints the free stack with [`STACK_PAINT`] (the peak stack is then the
//!   distance from the stack's top to the lowest word no longer painted), enables the UART,
//!   runs the binary's main function and exits with its code.
//! - Data stream: UART 0 (Arm's CMSDK APB UART at 0x4000_4000), both directions; in QEMU it is
//!   connected to a character device (`-serial chardev:ID`), e.g. the host's standard input and
//!   output. Reading sleeps until a byte arrives (the receive interrupt wakes the core, masked:
//!   no handler runs); writing waits while the transmit buffer is full.
//! - Diagnostics (descriptor 2) and the exit code: Arm semihosting (`bkpt 0xab`), which QEMU
//!   serves with `-semihosting-config enable=on,target=native` (text to its standard error,
//!   `SYS_EXIT_EXTENDED` as its exit status). A fault exits with [`EXIT_FAULT`].

/// The word the reset handler writes over the free stack.
pub const STACK_PAINT: u32 = 0x5354_4b21; // "!KTS" in memory: "STK!" as a word
/// Exit code of a hard fault (or any other exception: none is expected).
pub const EXIT_FAULT: i32 = 102;

// Arm's CMSDK documentation: the UART.
const UART0: usize = 0x4000_4000;
const UART_DATA: *mut u32 = UART0 as *mut u32;
const UART_STATE: *const u32 = (UART0 + 0x04) as *const u32;
const UART_CTRL: *mut u32 = (UART0 + 0x08) as *mut u32;
const UART_INTCLEAR: *mut u32 = (UART0 + 0x0C) as *mut u32;
const UART_BAUDDIV: *mut u32 = (UART0 + 0x10) as *mut u32;
const STATE_TX_FULL: u32 = 1 << 0;
const STATE_RX_FULL: u32 = 1 << 1;
const CTRL_TX_EN: u32 = 1 << 0;
const CTRL_RX_EN: u32 = 1 << 1;
const CTRL_RX_INT_EN: u32 = 1 << 3;
const INT_RX: u32 = 1 << 1;
/// The UART's receive interrupt: external interrupt 0 on this board.
const UART0_RX_IRQ: u32 = 0;
// The NVIC's set-enable and clear-pending registers for interrupts 0-31.
const NVIC_ISER0: *mut u32 = 0xE000_E100 as *mut u32;
const NVIC_ICPR0: *mut u32 = 0xE000_E280 as *mut u32;
/// 25 MHz peripheral clock / 217 = 115,200 baud on the board (QEMU does not pace the bytes).
const BAUDDIV_115200: u32 = 217;

// Semihosting operations (Arm's "Semihosting for AArch32 and AArch64").
const SYS_WRITEC: u32 = 0x03;
const SYS_EXIT_EXTENDED: u32 = 0x20;
const ADP_STOPPED_APPLICATION_EXIT: u32 = 0x2_0026;

/// Exception handlers after the initial stack pointer (which the linker script writes first).
#[unsafe(link_section = ".vector_table")]
#[used]
static VECTORS: [Option<unsafe extern "C" fn() -> !>; 15] = [
    Some(mpo_reset), // Reset
    Some(fault),     // NMI
    Some(fault),     // HardFault
    Some(fault),     // MemManage
    Some(fault),     // BusFault
    Some(fault),     // UsageFault
    None,
    None,
    None,
    None,
    Some(fault), // SVCall
    Some(fault), // DebugMonitor
    None,
    Some(fault), // PendSV
    Some(fault), // SysTick
];

unsafe extern "C" {
    fn mpo_reset() -> !;
}

// The FPU is enabled in assembly before any Rust code runs: a Rust function may use the FPU's
// registers anywhere (spills, copies), and the first such instruction with the FPU off would
// fault. Full access (bits 20-23 of the coprocessor access register CPACR, 0xE000_ED88) for
// both of its coprocessor numbers, then barriers so the next instruction sees it.
core::arch::global_asm!(
    ".section .text.mpo_reset,\"ax\",%progbits",
    ".global mpo_reset",
    ".type mpo_reset,%function",
    ".thumb_func",
    "mpo_reset:",
    "movw r0, #0xED88",
    "movt r0, #0xE000",
    "ldr r1, [r0]",
    "orr r1, r1, #0x00F00000",
    "str r1, [r0]",
    "dsb",
    "isb",
    "bl {start}",
    "udf #0",
    start = sym start,
);

unsafe extern "C" {
    static mut __sbss: u32;
    static mut __ebss: u32;
    static mut __sdata: u32;
    static mut __edata: u32;
    static __sidata: u32;
}

extern "C" fn start() -> ! {
    // SAFETY: the linker script's symbols bound word-aligned `.data` (RAM) with its load image
    // (flash) and `.bss`; nothing has used either yet.
    unsafe {
        let (mut d, end) = (&raw mut __sdata, &raw mut __edata);
        let mut s = &raw const __sidata;
        while d < end {
            d.write_volatile(s.read());
            d = d.add(1);
            s = s.add(1);
        }
        let (mut b, end) = (&raw mut __sbss, &raw mut __ebss);
        while b < end {
            b.write_volatile(0);
            b = b.add(1);
        }
        paint_stack(&raw mut __ebss);
        UART_BAUDDIV.write_volatile(BAUDDIV_115200);
        UART_CTRL.write_volatile(CTRL_TX_EN | CTRL_RX_EN | CTRL_RX_INT_EN);
        // The receive interrupt only wakes the core from `wfi` (see `wait_for_byte`): it is
        // enabled in the NVIC but never taken (PRIMASK masks every interrupt).
        core::arch::asm!("cpsid i", options(nomem, nostack, preserves_flags));
        NVIC_ISER0.write_volatile(1 << UART0_RX_IRQ);
    }
    exit(crate::run_main())
}

/// Writes [`STACK_PAINT`] over every word from `from` to 64 bytes below the stack pointer (this
/// function's own frame is above it and calls nothing).
///
/// # Safety
/// `from` is word-aligned and below the stack pointer, and nothing lives in between.
unsafe fn paint_stack(from: *mut u32) {
    // SAFETY: the caller's contract; the loop only stores below the live stack.
    unsafe {
        core::arch::asm!(
            "mov {end}, sp",
            "sub {end}, {end}, #64",
            "2:",
            "cmp {p}, {end}",
            "bhs 3f",
            "str {paint}, [{p}], #4",
            "b 2b",
            "3:",
            p = inout(reg) from => _,
            end = out(reg) _,
            paint = in(reg) STACK_PAINT,
            options(nostack),
        );
    }
}

/// Every exception but reset: a fault (nothing here enables an interrupt).
extern "C" fn fault() -> ! {
    write(2, b"fault\n");
    exit(EXIT_FAULT)
}

/// A semihosting call: operation `op` with parameter `arg`; the host's result.
fn semihosting(op: u32, arg: usize) -> u32 {
    let r: u32;
    // SAFETY: `bkpt 0xab` is the M-profile semihosting trap; QEMU (or a debugger) serves it
    // and returns in r0. `arg` points to a live block when the operation reads one.
    unsafe {
        core::arch::asm!("bkpt 0xab", inout("r0") op => r, in("r1") arg, options(nostack));
    }
    r
}

/// Reads what the UART has (descriptor 0), waiting for the first byte: at least one byte for a
/// non-empty `buf` (a UART has no end of input). -1 for another descriptor.
pub fn read(fd: u32, buf: &mut [u8]) -> isize {
    if fd != 0 {
        return -1;
    }
    if buf.is_empty() {
        return 0;
    }
    wait_for_byte();
    let mut n = 0;
    // SAFETY: the UART's registers (device memory, always mapped).
    while n < buf.len() && unsafe { UART_STATE.read_volatile() } & STATE_RX_FULL != 0 {
        buf[n] = unsafe { UART_DATA.read_volatile() } as u8;
        n += 1;
    }
    n as isize
}

/// Sleeps (`wfi`) until the UART holds a received byte. The receive interrupt, pending but
/// masked, wakes the core; it is then cleared (at the UART and in the NVIC) before the state is
/// read again, so a byte that arrives in between is never missed. Sleeping rather than polling
/// matters in QEMU: a polling core competes with the thread that delivers the bytes, which made
/// each byte take tens of microseconds.
fn wait_for_byte() {
    // SAFETY: the UART's and the NVIC's registers; `wfi` only waits.
    unsafe {
        while UART_STATE.read_volatile() & STATE_RX_FULL == 0 {
            core::arch::asm!("wfi", options(nomem, nostack, preserves_flags));
            UART_INTCLEAR.write_volatile(INT_RX);
            NVIC_ICPR0.write_volatile(1 << UART0_RX_IRQ);
        }
    }
}

/// Writes bytes: descriptor 1 to the UART (waiting while its transmit buffer is full), 2 to
/// the semihosting console. Returns the count written, -1 for another descriptor.
pub fn write(fd: u32, bytes: &[u8]) -> isize {
    match fd {
        1 => {
            for &b in bytes {
                // SAFETY: the UART's registers.
                unsafe {
                    while UART_STATE.read_volatile() & STATE_TX_FULL != 0 {}
                    UART_DATA.write_volatile(b as u32);
                }
            }
        }
        2 => {
            for b in bytes {
                semihosting(SYS_WRITEC, b as *const u8 as usize);
            }
        }
        _ => return -1,
    }
    bytes.len() as isize
}

/// Ends the program with `code` (semihosting `SYS_EXIT_EXTENDED`: QEMU exits with it).
pub fn exit(code: i32) -> ! {
    let block = [ADP_STOPPED_APPLICATION_EXIT, code as u32];
    semihosting(SYS_EXIT_EXTENDED, block.as_ptr() as usize);
    // Without a semihosting host the call does not return either (it faults); spin if it did.
    loop {
        core::hint::spin_loop();
    }
}
