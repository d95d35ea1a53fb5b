//! Test support shared by the cross-crate tests in `tests/` and the benchmarks in `benches/`.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};

/// Allocations on every thread (for code that runs on worker threads).
static ALL_THREADS: AtomicU64 = AtomicU64::new(0);

thread_local! {
    // const-initialised and without Drop, so touching it never allocates or registers a
    // destructor (which would itself count).
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

/// A global allocator that counts heap allocations per thread (parallel tests do not disturb
/// each other's counts) and over all threads. Install it in a test binary with
/// `#[global_allocator] static A: CountingAlloc = CountingAlloc;`.
pub struct CountingAlloc;

// SAFETY: forwards every call to the system allocator unchanged; only counts.
unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        ALL_THREADS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        ALL_THREADS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        ALL_THREADS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
}

/// Runs `f` and returns its result with the number of heap allocations it made on this
/// thread (meaningful only in a binary whose global allocator is [`CountingAlloc`]).
pub fn count_allocations<R>(f: impl FnOnce() -> R) -> (R, u64) {
    let before = ALLOCATIONS.with(Cell::get);
    let r = f();
    (r, ALLOCATIONS.with(Cell::get) - before)
}

/// Runs `f` and returns its result with the number of heap allocations made on every thread
/// meanwhile (for work spread over a thread pool; meaningful only in a test binary where
/// nothing else runs at the same time).
pub fn count_allocations_all_threads<R>(f: impl FnOnce() -> R) -> (R, u64) {
    let before = ALL_THREADS.load(Ordering::SeqCst);
    let r = f();
    (r, ALL_THREADS.load(Ordering::SeqCst) - before)
}

/// The workspace root (for tests that build or run other parts of the repository).
pub fn workspace_root() -> std::path::PathBuf {
    std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `cargo build --release` of a freestanding crate under `freestanding/` for the baseline
/// x86-64 CPU (`RUSTFLAGS` replaces the workspace's config flags: no target-cpu, no rpath),
/// with extra `features` and environment, into `target_dir`.
pub fn build_freestanding(
    krate: &str,
    features: &str,
    env: &[(&str, &std::ffi::OsStr)],
    target_dir: &std::path::Path,
) -> std::process::Output {
    let mut cmd =
        std::process::Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()));
    cmd.current_dir(workspace_root().join("freestanding").join(krate))
        .args([
            "build",
            "--release",
            "--target",
            "x86_64-unknown-linux-gnu",
            "--target-dir",
        ])
        .arg(target_dir)
        .env("RUSTFLAGS", "-C target-cpu=x86-64")
        .env_remove("CARGO_ENCODED_RUSTFLAGS");
    for (k, v) in env {
        cmd.env(k, v);
    }
    if !features.is_empty() {
        cmd.args(["--features", features]);
    }
    cmd.output().expect("failed to spawn cargo")
}

/// Asserts that a build with each `(feature, expected error text)` fails, for that reason:
/// the negative controls that show a "does not link with std/alloc" check has teeth.
pub fn assert_builds_fail(cases: &[(&str, &str)], build: impl Fn(&str) -> std::process::Output) {
    for (feature, expect) in cases {
        let out = build(feature);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success(),
            "build with {feature} succeeded; the check has no teeth"
        );
        assert!(
            err.contains(expect),
            "build with {feature} failed for another reason:\n{err}"
        );
    }
}

/// Building and running the inference-only firmware (`freestanding/firmware`).
pub mod firmware {
    use std::path::{Path, PathBuf};
    use std::process::Output;

    use mpo_core::actor::Actor;

    /// Writes `actor` as the firmware's policy source (`mpo_core::export`) to `path`.
    pub fn export<
        const OBS: usize,
        const ACT: usize,
        const TRI: usize,
        const H1: usize,
        const H2: usize,
    >(
        actor: &Actor<OBS, ACT, TRI, H1, H2>,
        origin: &str,
        path: &Path,
    ) {
        let mut src = String::new();
        mpo_core::export::write_actor_source(actor, origin, &mut src).unwrap();
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, src).unwrap();
    }

    /// Builds the firmware with the policy source `policy` and extra `features`.
    pub fn build(policy: &Path, features: &str, target_dir: &Path) -> Output {
        super::build_freestanding(
            "firmware",
            features,
            &[("MPO_FIRMWARE_WEIGHTS", policy.as_os_str())],
            target_dir,
        )
    }

    /// Runs the x86_64 firmware `bin` on `obs` (records of little-endian f32s on its stdin)
    /// and returns what it wrote to stdout; panics if it does not exit successfully.
    pub fn run<const OBS: usize>(bin: &Path, obs: &[[f32; OBS]]) -> Vec<u8> {
        use std::io::Write;
        use std::process::{Command, Stdio};
        let input: Vec<u8> = obs.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
        let mut child = Command::new(bin)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("failed to run the firmware");
        let mut stdin = child.stdin.take().unwrap();
        let writer = std::thread::spawn(move || stdin.write_all(&input));
        let result = child.wait_with_output().unwrap();
        writer.join().unwrap().unwrap();
        assert!(
            result.status.success(),
            "firmware exited with {:?}",
            result.status
        );
        result.stdout
    }

    /// Exports `actor` and builds the firmware under `target/firmware/NAME/`; returns the
    /// binary's path (panics with cargo's output if the build fails).
    pub fn export_and_build<
        const OBS: usize,
        const ACT: usize,
        const TRI: usize,
        const H1: usize,
        const H2: usize,
    >(
        actor: &Actor<OBS, ACT, TRI, H1, H2>,
        name: &str,
    ) -> PathBuf {
        let dir = super::workspace_root().join("target/firmware").join(name);
        let src = dir.join("policy.rs");
        export(actor, name, &src);
        let out = build(&src, "", &dir.join("build"));
        assert!(
            out.status.success(),
            "firmware build failed:\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        dir.join("build/x86_64-unknown-linux-gnu/release/mpo-firmware")
    }

    /// Exports `actor` and builds the firmware for the Cortex-M4F; returns the ELF's path,
    /// `target/cortex-m/firmware/NAME.elf` (panics with cargo's output if the build fails).
    /// Every policy builds in the one target directory `target/cortex-m` (so `core` is built
    /// once), one build at a time.
    pub fn export_and_build_cortex_m<
        const OBS: usize,
        const ACT: usize,
        const TRI: usize,
        const H1: usize,
        const H2: usize,
    >(
        actor: &Actor<OBS, ACT, TRI, H1, H2>,
        name: &str,
    ) -> PathBuf {
        static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());
        let _guard = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
        let target = super::workspace_root().join("target/cortex-m");
        let dir = target.join("firmware");
        let src = dir.join(format!("{name}.rs"));
        export(actor, name, &src);
        let out = super::cortex_m::build(
            "firmware",
            "",
            &[("MPO_FIRMWARE_WEIGHTS", src.as_os_str())],
            &target,
        );
        assert!(
            out.status.success(),
            "firmware build for the Cortex-M4F failed:\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let elf = dir.join(format!("{name}.elf"));
        std::fs::copy(super::cortex_m::elf(&target, "mpo-firmware"), &elf).unwrap();
        elf
    }
}

/// Building the freestanding binaries for the Cortex-M4F (thumbv7em-none-eabihf) and running
/// them on QEMU's `mps2-an386` board (`scripts/setup-cortex-m` installs what this needs;
/// `scripts/cortex-m-cargo` builds).
pub mod cortex_m {
    use std::ffi::OsStr;
    use std::io::{Read, Write};
    use std::path::{Path, PathBuf};
    use std::process::{Command, Output, Stdio};
    use std::time::Duration;

    use super::workspace_root as root;

    /// The target triple.
    pub const TARGET: &str = "thumbv7em-none-eabihf";

    /// What to run when something is missing.
    pub const SETUP: &str = "scripts/setup-cortex-m (as root or with sudo: it installs the \
        Debian packages rustc-web cargo-web rust-web-src lld-16 binutils-arm-none-eabi gcc and \
        unpacks qemu-system-arm 7.2 into .deps/qemu)";

    /// QEMU for Arm, as `scripts/setup-cortex-m` unpacks it.
    pub fn qemu() -> PathBuf {
        root().join(".deps/qemu/usr/bin/qemu-system-arm")
    }

    /// The instruction counter (`scripts/qemu-count`), as the setup script builds it.
    pub fn counter() -> PathBuf {
        root().join("target/cortex-m/libqemu-count.so")
    }

    /// Panics with the setup command unless Debian's Rust, the linker, binutils for Arm, QEMU
    /// and the instruction counter are all there: the tests that need them fail, never skip.
    pub fn require() {
        let tools = [
            PathBuf::from("/usr/bin/rustc"),
            PathBuf::from("/usr/bin/cargo"),
            PathBuf::from("/usr/lib/rustlib/src/rust/library/core"),
            PathBuf::from("/usr/bin/ld.lld-16"),
            PathBuf::from("/usr/bin/arm-none-eabi-nm"),
            qemu(),
            counter(),
        ];
        let missing: Vec<String> = tools
            .iter()
            .filter(|p| !p.exists())
            .map(|p| p.display().to_string())
            .collect();
        assert!(
            missing.is_empty(),
            "the Cortex-M tools are missing ({}): run {SETUP}",
            missing.join(", ")
        );
    }

    /// A board QEMU models, and the code generation for its CPU.
    pub struct Board {
        /// QEMU's machine.
        pub machine: &'static str,
        /// Extra compiler flags for its CPU (`MPO_CORTEX_M_RUSTFLAGS` of
        /// `scripts/cortex-m-cargo`).
        pub rustflags: &'static str,
    }

    /// Arm's MPS2 with the AN386 image: a Cortex-M4F (single-precision FPU). The board the
    /// binaries are built for.
    pub const MPS2_AN386: Board = Board {
        machine: "mps2-an386",
        rustflags: "",
    };

    /// Arm's MPS2 with the AN500 image: a Cortex-M7 with a double-precision FPU (the same
    /// memory map and UART as the AN386), with code generated for that CPU (f64 arithmetic in
    /// hardware).
    pub const MPS2_AN500: Board = Board {
        machine: "mps2-an500",
        rustflags: "-C target-cpu=cortex-m7",
    };

    /// `cargo build --release` of a crate under `freestanding/` for the Cortex-M4F through
    /// `scripts/cortex-m-cargo`, with extra `features` and environment, into `target_dir`.
    pub fn build(krate: &str, features: &str, env: &[(&str, &OsStr)], target_dir: &Path) -> Output {
        build_for(&MPS2_AN386, krate, features, env, target_dir)
    }

    /// [`build`] for `board`'s CPU.
    pub fn build_for(
        board: &Board,
        krate: &str,
        features: &str,
        env: &[(&str, &OsStr)],
        target_dir: &Path,
    ) -> Output {
        require();
        let manifest = root().join("freestanding").join(krate).join("Cargo.toml");
        let mut cmd = Command::new(root().join("scripts/cortex-m-cargo"));
        cmd.args(["build", "--release", "--manifest-path"])
            .arg(manifest)
            .arg("--target-dir")
            .arg(target_dir);
        if !features.is_empty() {
            cmd.args(["--features", features]);
        }
        cmd.env("MPO_CORTEX_M_RUSTFLAGS", board.rustflags);
        for (k, v) in env {
            cmd.env(k, v);
        }
        cmd.output().expect("failed to run scripts/cortex-m-cargo")
    }

    /// The ELF of binary `name` built into `target_dir` by [`build`].
    pub fn elf(target_dir: &Path, name: &str) -> PathBuf {
        target_dir.join(TARGET).join("release").join(name)
    }

    /// The value of symbol `name` in `elf` (`arm-none-eabi-nm`).
    pub fn symbol(elf: &Path, name: &str) -> u64 {
        let out = Command::new("arm-none-eabi-nm")
            .arg(elf)
            .output()
            .expect("arm-none-eabi-nm");
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .find_map(|l| {
                let mut it = l.split_whitespace();
                let (v, _, n) = (it.next()?, it.next()?, it.next()?);
                (n == name).then(|| u64::from_str_radix(v, 16).unwrap())
            })
            .unwrap_or_else(|| panic!("no symbol {name} in {}", elf.display()))
    }

    /// The QEMU command line that runs `elf` on the board: its UART on QEMU's standard input
    /// and output (a raw byte stream: no monitor, no terminal handling), semihosting for
    /// diagnostics (standard error) and the exit code. With `count_into`, the instruction
    /// counter is loaded with the addresses of the binary's marks and writes into that file.
    /// No argument contains a space (`mpo train --device` splits at whitespace).
    pub fn command(elf: &Path, count_into: Option<&Path>) -> Vec<String> {
        command_with(&MPS2_AN386, elf, count_into, false, None)
    }

    /// [`command`] on `board`, with the counter's per-instruction histogram (`histogram`) and
    /// a QMP control socket at `qmp` (for [`Qmp`]: the benchmarks read the stack's paint and
    /// stop QEMU cleanly, so the counter writes its histogram).
    pub fn command_with(
        board: &Board,
        elf: &Path,
        count_into: Option<&Path>,
        histogram: bool,
        qmp: Option<&Path>,
    ) -> Vec<String> {
        let mut c: Vec<String> = [
            qemu().display().to_string().as_str(),
            "-M",
            board.machine,
            "-display",
            "none",
            "-monitor",
            "none",
            "-chardev",
            "stdio,id=uart,signal=off",
            "-serial",
            "chardev:uart",
            "-semihosting-config",
            "enable=on,target=native",
            "-kernel",
            &elf.display().to_string(),
        ]
        .map(String::from)
        .to_vec();
        if let Some(log) = count_into {
            c.push("-plugin".into());
            c.push(format!(
                "{},begin={:#x},end={:#x}{}",
                counter().display(),
                symbol(elf, "mpo_mark_begin"),
                symbol(elf, "mpo_mark_end"),
                if histogram { ",histogram=1" } else { "" },
            ));
            c.extend(["-d".into(), "plugin".into(), "-D".into()]);
            c.push(log.display().to_string());
        }
        if let Some(socket) = qmp {
            c.push("-qmp".into());
            c.push(format!("unix:{},server=on,wait=off", socket.display()));
        }
        for a in &c {
            assert!(!a.contains(char::is_whitespace), "a path with a space: {a}");
        }
        c
    }

    /// Runs `command`, writes `input` to the board's UART and returns the first `len` bytes it
    /// sends back; then stops QEMU (a UART has no end of input, so the program never exits by
    /// itself). Panics if the bytes do not come within `timeout`, or QEMU exits first.
    pub fn exchange(command: &[String], input: Vec<u8>, len: usize, timeout: Duration) -> Vec<u8> {
        exchange_until(command, input, move |got| got.len() >= len, timeout)
    }

    /// [`exchange`] until `done` holds for the bytes received so far.
    pub fn exchange_until(
        command: &[String],
        input: Vec<u8>,
        done: impl Fn(&[u8]) -> bool + Send + 'static,
        timeout: Duration,
    ) -> Vec<u8> {
        session(command, input, done, timeout, || false)
    }

    /// [`exchange_until`], then `at_end` while QEMU still runs (e.g. [`Qmp`] commands); if it
    /// returns true, QEMU is ending by itself (QMP `quit`) and is waited for, else it is killed.
    pub fn session(
        command: &[String],
        input: Vec<u8>,
        done: impl Fn(&[u8]) -> bool + Send + 'static,
        timeout: Duration,
        at_end: impl FnOnce() -> bool,
    ) -> Vec<u8> {
        let mut child = Command::new(&command[0])
            .args(&command[1..])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("failed to start qemu-system-arm");
        let mut stdin = child.stdin.take().unwrap();
        let mut stdout = child.stdout.take().unwrap();
        // The writer keeps the pipe open until QEMU is stopped: the end of QEMU's input is not
        // the program's.
        let (stop, stopped) = std::sync::mpsc::channel::<()>();
        std::thread::spawn(move || {
            let _ = stdin.write_all(&input);
            let _ = stopped.recv();
        });
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut got = Vec::new();
            let mut buf = [0u8; 4096];
            let r = loop {
                if done(&got) {
                    break Ok(got);
                }
                match stdout.read(&mut buf) {
                    Ok(0) => break Err(got),
                    Ok(n) => got.extend_from_slice(&buf[..n]),
                    Err(_) => break Err(got),
                }
            };
            let _ = tx.send(r);
        });
        let got = rx.recv_timeout(timeout);
        if !(got.is_ok() && at_end()) {
            let _ = child.kill();
        }
        drop(stop);
        let out = child.wait_with_output().unwrap();
        match got {
            Ok(Ok(bytes)) => bytes,
            other => panic!(
                "the board did not send what was expected within {timeout:?} ({}): {:?}\nstderr: {}",
                out.status,
                other.map(|r| r.unwrap_or_else(|e| e).len()),
                String::from_utf8_lossy(&out.stderr)
            ),
        }
    }

    /// The instruction counts of the marked spans in a counter's log: for each `B` line
    /// followed by an `E` line, the instructions between them (including the marks' own three:
    /// `mpo_mark_begin`'s `nop` and return, and the call to `mpo_mark_end`).
    pub fn spans(log: &Path) -> Vec<u64> {
        let text = std::fs::read_to_string(log).expect("the counter's log");
        let mut spans = Vec::new();
        let mut begin = None;
        for line in text.lines() {
            let mut it = line.split_whitespace();
            match (it.next(), it.next().and_then(|v| v.parse::<u64>().ok())) {
                (Some("B"), Some(n)) => begin = Some(n),
                (Some("E"), Some(n)) => {
                    let b = begin.take().expect("an E line without its B line");
                    spans.push(n - b);
                }
                _ => {}
            }
        }
        spans
    }

    /// A QMP connection (QEMU's JSON control protocol) on a Unix socket.
    pub struct Qmp(std::io::BufReader<std::os::unix::net::UnixStream>);

    impl Qmp {
        /// Connects (waiting up to 10 s for QEMU to open the socket) and leaves the
        /// negotiation mode.
        pub fn connect(socket: &Path) -> Self {
            let mut tries = 0;
            let stream = loop {
                match std::os::unix::net::UnixStream::connect(socket) {
                    Ok(s) => break s,
                    Err(e) if tries < 100 => {
                        tries += 1;
                        let _ = e;
                        std::thread::sleep(Duration::from_millis(100));
                    }
                    Err(e) => panic!("QMP socket {}: {e}", socket.display()),
                }
            };
            let mut q = Self(std::io::BufReader::new(stream));
            let mut greeting = String::new();
            std::io::BufRead::read_line(&mut q.0, &mut greeting).unwrap();
            q.execute(r#"{"execute":"qmp_capabilities"}"#);
            q
        }

        /// Sends one command (a JSON object) and returns its reply line (panics on an error).
        pub fn execute(&mut self, command: &str) -> String {
            self.0.get_mut().write_all(command.as_bytes()).unwrap();
            self.0.get_mut().write_all(b"\n").unwrap();
            loop {
                let mut line = String::new();
                let n = std::io::BufRead::read_line(&mut self.0, &mut line).unwrap();
                assert!(n > 0, "QMP closed during {command}");
                if line.starts_with(r#"{"return""#) {
                    return line;
                }
                assert!(!line.starts_with(r#"{"error""#), "QMP {command}: {line}");
            }
        }

        /// The guest's physical memory `[at, at + len)`.
        pub fn memory(&mut self, at: u64, len: u64) -> Vec<u8> {
            let file = std::env::temp_dir().join(format!("mpo-qmp-{}-{at:x}", std::process::id()));
            self.execute(&format!(
                r#"{{"execute":"pmemsave","arguments":{{"val":{at},"size":{len},"filename":"{}"}}}}"#,
                file.display()
            ));
            let bytes = std::fs::read(&file).unwrap();
            let _ = std::fs::remove_file(&file);
            bytes
        }

        /// Asks QEMU to exit (cleanly: the counter writes its last lines).
        pub fn quit(mut self) {
            self.execute(r#"{"execute":"quit"}"#);
        }
    }

    /// The peak stack of a run of `elf` so far, in bytes: the reset handler painted every word
    /// from the end of `.bss` to the top of the stack with the paint word; the lowest word that
    /// is no longer paint marks the deepest the stack has been.
    pub fn peak_stack(qmp: &mut Qmp, elf: &Path) -> u64 {
        const PAINT: u32 = 0x5354_4b21; // freestanding/rt/src/mps2.rs, STACK_PAINT
        let (bottom, top) = (symbol(elf, "__ebss"), symbol(elf, "__stack_top"));
        let ram = qmp.memory(bottom, top - bottom);
        let painted = ram
            .chunks_exact(4)
            .take_while(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]]) == PAINT)
            .count() as u64;
        top - bottom - 4 * painted
    }

    /// Section sizes of an ELF (`arm-none-eabi-size -A`).
    pub fn sections(elf: &Path) -> std::collections::BTreeMap<String, u64> {
        let out = Command::new("arm-none-eabi-size")
            .arg("-A")
            .arg(elf)
            .output()
            .expect("arm-none-eabi-size");
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .filter_map(|l| {
                let mut it = l.split_whitespace();
                let (name, size) = (it.next()?, it.next()?.parse().ok()?);
                name.starts_with('.').then(|| (name.to_string(), size))
            })
            .collect()
    }

    /// The counter's histogram lines (`H address executions`) in its log.
    pub fn histogram(log: &Path) -> Vec<(u64, u64)> {
        std::fs::read_to_string(log)
            .expect("the counter's log")
            .lines()
            .filter_map(|l| {
                let mut it = l.split_whitespace();
                (it.next()? == "H").then_some(())?;
                let at = u64::from_str_radix(it.next()?, 16).ok()?;
                Some((at, it.next()?.parse().ok()?))
            })
            .collect()
    }
}
