//! `mpo`: the command with the built-in rows' learners (and those `sizes/local.toml` asks
//! for); see [`mpo_host::main_with`].

fn main() -> std::process::ExitCode {
    mpo_host::main_with(Vec::new())
}
