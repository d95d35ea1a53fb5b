//! `mpo-controller`: serves one run's observations with a policy over iceoryx2.
//!
//! ```text
//! mpo-controller --run <id> [--profile hopper-256] [--wait event|busy-poll] [--seed N]
//!                [--init-std S] [--realtime PRIO]
//! ```
//!
//! Prints one `ready` line on stdout when its ports are open and one `stats ...` line on exit
//! (SIGINT/SIGTERM), then exits 0 with its iceoryx2 resources removed.

use std::io::Write;
use std::process::ExitCode;

use mpo_link::controller::{ControllerOptions, PROFILES, install_stop_handler, serve};
use mpo_link::{RunId, WaitMode, with_profile};

const USAGE: &str = "usage: mpo-controller --run <id> [--profile NAME] [--wait event|busy-poll] \
[--seed N] [--init-std S] [--realtime PRIO]";

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("mpo-controller: {e}");
            ExitCode::from(2)
        }
    }
}

// Long for its flag list (one `match` arm per flag) and the help text it refers to.
fn run() -> Result<(), String> {
    let mut run = None;
    let mut profile = "hopper-256".to_string();
    let mut wait = WaitMode::Event;
    let mut seed = 0u64;
    let mut init_std = 1.0f32;
    let mut realtime = None;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || {
            args.next()
                .ok_or_else(|| format!("{a} needs a value\n{USAGE}"))
        };
        match a.as_str() {
            "--run" => run = Some(RunId::parse(&value()?).map_err(|e| e.to_string())?),
            "--profile" => profile = value()?,
            "--wait" => {
                let v = value()?;
                wait = WaitMode::parse(&v).ok_or(format!("unknown wait mode {v:?}"))?;
            }
            "--seed" => seed = value()?.parse().map_err(|e| format!("--seed: {e}"))?,
            "--init-std" => init_std = value()?.parse().map_err(|e| format!("--init-std: {e}"))?,
            "--realtime" => {
                realtime = Some(value()?.parse().map_err(|e| format!("--realtime: {e}"))?)
            }
            "-h" | "--help" => {
                println!("{USAGE}\nprofiles: {}", PROFILES.join(", "));
                return Ok(());
            }
            _ => return Err(format!("unknown argument {a:?}\n{USAGE}")),
        }
    }
    let run = run.ok_or(format!("--run is required\n{USAGE}"))?;
    if !(init_std.is_finite() && init_std > 1e-4) {
        return Err("--init-std must be finite and above 1e-4".into());
    }
    if let Some(prio) = realtime {
        if wait == WaitMode::BusyPoll {
            return Err("--realtime with --wait busy-poll would starve the core".into());
        }
        mpo_link::realtime::enter(prio)?;
    }
    install_stop_handler();
    let opts = ControllerOptions {
        run,
        wait,
        seed,
        init_std,
    };
    let ready = || {
        let mut out = std::io::stdout();
        let _ = writeln!(out, "ready");
        let _ = out.flush();
    };
    let stats = with_profile!(
        profile.as_str(),
        serve(&opts, ready),
        return Err(format!(
            "unknown profile {profile:?}; known: {}",
            PROFILES.join(", ")
        ))
    )
    .map_err(|e| e.to_string())?;
    // Whoever started us may have closed our stdout already: not an error at shutdown.
    let _ = writeln!(std::io::stdout(), "{stats}");
    Ok(())
}
