//! `sim-bridge-engine`: the `sim-bridge` command itself (normally started by the `sim-bridge`
//! launcher, which checks first that libmujoco loads).

use clap::Parser;

fn main() {
    if let Err(message) = sim_bridge::launcher::check_engine_matches_launcher() {
        eprintln!("error: {message}");
        std::process::exit(1);
    }
    let cli = sim_bridge::cli::Cli::parse();
    if let Err(sim_bridge::cli::CliError(message)) = sim_bridge::cli::run(cli) {
        eprintln!("error: {message}");
        std::process::exit(1);
    }
}
