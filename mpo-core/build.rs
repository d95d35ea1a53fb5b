//! Sets `cfg(mpo_avx512f)` when the CPU building a native x86-64 build has AVX-512F: the
//! tests of the 512-bit kernels (`linear::wide`) are compiled only then, since elsewhere
//! their code cannot run (and a test that cannot run must not count as passed).

fn main() {
    println!("cargo::rustc-check-cfg=cfg(mpo_avx512f)");
    println!("cargo::rerun-if-changed=build.rs");
    let env = |k: &str| std::env::var(k).unwrap_or_default();
    let native = env("HOST") == env("TARGET") && env("CARGO_CFG_TARGET_ARCH") == "x86_64";
    if native && avx512f() {
        println!("cargo::rustc-cfg=mpo_avx512f");
    }
}

#[cfg(target_arch = "x86_64")]
fn avx512f() -> bool {
    std::arch::is_x86_feature_detected!("avx512f")
}

#[cfg(not(target_arch = "x86_64"))]
fn avx512f() -> bool {
    false
}
