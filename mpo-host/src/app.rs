//! The `mpo` program: parses flags, runs the command from [`crate::commands`], maps errors to
//! exit codes (0 success, 1 error, 2 usage, 3 a learner of new sizes is needed: rebuild, 130
//! interrupted with a checkpoint written).

use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Context;
use clap::Parser;

use crate::cli::{Cli, Command};
use crate::commands;
use crate::registry::EXIT_REBUILD;
use crate::spec::Instance;

static INTERRUPT: AtomicBool = AtomicBool::new(false);

/// Runs `mpo` with the built-in instantiations and `extra`: a Rust program that keeps its
/// robot's learner sizes in its own crate declares them with [`crate::spec!`] and calls this
/// from its `main`:
///
/// ```no_run
/// mpo_host::spec! {
///     pub MyRobot = obs 11, act 2, actor [256, 256], critic [256, 256], batch 256 / 4,
///         seq 8, samples 20 20, replay 1_000_000;
/// }
/// fn main() -> std::process::ExitCode {
///     mpo_host::main_with(vec![mpo_host::spec::Instance::of::<MyRobot>()])
/// }
/// ```
pub fn main_with(extra: Vec<Instance>) -> ExitCode {
    crate::registry::register(extra);
    let cli = Cli::parse();
    let _plants = crate::plant::Session::begin(cli.command.plant_args());
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            if let Some(commands::Error::MissingInstance(m)) = e.downcast_ref() {
                return missing_instance(m);
            }
            eprintln!("error: {e:#}");
            ExitCode::from(1)
        }
    }
}

/// A task's sizes without a learner in this build: asks the source tree's build for them and
/// exits with [`EXIT_REBUILD`], on which `./mpo` rebuilds and runs the command again.
fn missing_instance(m: &crate::registry::MissingInstance) -> ExitCode {
    match m.request() {
        Ok(true) => {
            eprintln!(
                "mpo: this build has no learner of sizes {}; added them to {}: rebuild \
                 (`cargo build --release -p mpo-host`; `./mpo` does it and runs the command again)",
                m.sizes.describe(),
                m.file.display()
            );
            ExitCode::from(EXIT_REBUILD)
        }
        Ok(false) => {
            eprintln!("error: {m}");
            ExitCode::from(1)
        }
        Err(e) => {
            eprintln!("error: {m}; writing {} failed: {e}", m.file.display());
            ExitCode::from(1)
        }
    }
}

fn on_ctrl_c(train: bool) -> anyhow::Result<()> {
    ctrlc::set_handler(move || {
        if INTERRUPT.swap(true, Ordering::SeqCst) {
            if train {
                eprintln!("\nsecond Ctrl-C: exiting now; the last checkpoint is kept");
            }
            std::process::exit(130);
        }
        if train {
            eprintln!(
                "\nCtrl-C: finishing the current episode, then writing a checkpoint (Ctrl-C again to exit at once)"
            );
        }
    })
    .context("installing the Ctrl-C handler")
}

fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    let interrupted = |yes: bool| match yes {
        true => ExitCode::from(130),
        false => ExitCode::SUCCESS,
    };
    match cli.command {
        Command::Train(args) if args.print_config => {
            print!("{}", commands::print_config(&args)?);
            Ok(ExitCode::SUCCESS)
        }
        Command::Train(args) => {
            on_ctrl_c(true)?;
            let summary = commands::train(&args, &INTERRUPT)?;
            println!("{}", serde_json::to_string(&summary)?);
            Ok(interrupted(summary.interrupted))
        }
        Command::Run(args) => {
            on_ctrl_c(false)?;
            let s = commands::run(&args, &INTERRUPT)?;
            eprint!("{}", crate::run::table(&s));
            println!("{}", serde_json::to_string(&s)?);
            Ok(interrupted(s.interrupted))
        }
        Command::Controller(args) => {
            let stats = commands::controller(&args)?;
            // Whoever started us may have closed our stdout already: not an error at shutdown.
            use std::io::Write;
            let _ = writeln!(std::io::stdout(), "{stats}");
            Ok(ExitCode::SUCCESS)
        }
        Command::PlantWorker(args) => {
            commands::plant_worker(&args)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Eval(args) => {
            println!("{}", serde_json::to_string(&commands::eval(&args)?)?);
            Ok(ExitCode::SUCCESS)
        }
        Command::Render(args) => {
            println!("{}", serde_json::to_string(&commands::render(&args)?)?);
            Ok(ExitCode::SUCCESS)
        }
        Command::Export(args) => {
            println!("{}", serde_json::to_string(&commands::export(&args)?)?);
            Ok(ExitCode::SUCCESS)
        }
        Command::Plot(args) => {
            commands::plot(&args)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Tasks(args) => {
            print!("{}", commands::tasks_listing(&args.task_file));
            Ok(ExitCode::SUCCESS)
        }
    }
}
