//! The `compend` command line. Each subcommand lives in `src/cli/<name>.rs`.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod cli;

#[derive(Parser, Debug)]
#[command(name = "compend", version, about = "Projector-camera compensation: make a projector look right on any surface", long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// PSNR, RMSE and SSIM (paper conventions) of two PNGs or two folders of same-named PNGs.
    Metrics(cli::metrics::Args),
    /// The virtual rig: simulated projector-camera scenes (list, show, export).
    Sim(cli::sim::Args),
}

fn main() -> ExitCode {
    let args = Cli::parse();
    let result = match args.command {
        Command::Metrics(a) => cli::metrics::run(a),
        Command::Sim(a) => cli::sim::run(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("compend: error: {err:#}");
            ExitCode::from(cli::exit_code(&err))
        }
    }
}
