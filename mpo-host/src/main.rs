//! `mpo`: parses flags, runs the command from the library, maps errors to exit codes
//! (0 success, 1 error, 2 usage, 130 interrupted with a checkpoint written).

use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Context;
use clap::Parser;
use mpo_host::cli::{Cli, Command};
use mpo_host::commands;

static INTERRUPT: AtomicBool = AtomicBool::new(false);

fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    match cli.command {
        Command::Train(args) if args.print_config => {
            print!("{}", commands::print_config(&args)?);
            Ok(ExitCode::SUCCESS)
        }
        Command::Train(args) => {
            ctrlc::set_handler(|| {
                if INTERRUPT.swap(true, Ordering::SeqCst) {
                    eprintln!("\nsecond Ctrl-C: exiting now; the last checkpoint is kept");
                    std::process::exit(130);
                }
                eprintln!("\nCtrl-C: finishing the current episode, then writing a checkpoint (Ctrl-C again to exit at once)");
            })
            .context("installing the Ctrl-C handler")?;
            let summary = commands::train(&args, &INTERRUPT)?;
            println!("{}", serde_json::to_string(&summary)?);
            Ok(if summary.interrupted {
                ExitCode::from(130)
            } else {
                ExitCode::SUCCESS
            })
        }
        Command::Run(args) => {
            ctrlc::set_handler(|| {
                if INTERRUPT.swap(true, Ordering::SeqCst) {
                    std::process::exit(130);
                }
            })
            .context("installing the Ctrl-C handler")?;
            let s = commands::run(&args, &INTERRUPT)?;
            eprint!("{}", mpo_host::run::table(&s));
            println!("{}", serde_json::to_string(&s)?);
            Ok(if s.interrupted {
                ExitCode::from(130)
            } else {
                ExitCode::SUCCESS
            })
        }
        Command::Controller(args) => {
            let stats = commands::controller(&args)?;
            // Whoever started us may have closed our stdout already: not an error at shutdown.
            use std::io::Write;
            let _ = writeln!(std::io::stdout(), "{stats}");
            Ok(ExitCode::SUCCESS)
        }
        Command::Eval(args) => {
            let s = commands::eval(&args)?;
            println!("{}", serde_json::to_string(&s)?);
            Ok(ExitCode::SUCCESS)
        }
        Command::Render(args) => {
            let s = commands::render(&args)?;
            println!("{}", serde_json::to_string(&s)?);
            Ok(ExitCode::SUCCESS)
        }
        Command::Export(args) => {
            let s = commands::export(&args)?;
            println!("{}", serde_json::to_string(&s)?);
            Ok(ExitCode::SUCCESS)
        }
        Command::Plot(args) => {
            commands::plot(&args)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Tasks => {
            print!("{}", commands::tasks_listing());
            Ok(ExitCode::SUCCESS)
        }
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(1)
        }
    }
}
