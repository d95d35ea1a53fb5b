//! `sim-bridge`: checks that MuJoCo can be loaded, then runs `sim-bridge-engine` (see
//! `sim_bridge::launcher` for why the command is split in two).

fn main() {
    let message = sim_bridge::launcher::launch(std::env::args_os().skip(1).collect());
    eprintln!("error: {message}");
    std::process::exit(1);
}
