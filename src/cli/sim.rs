//! `compend sim ...`: the virtual rig from the command line.
//!
//! - `compend sim list`: the built-in scene names, one per line.
//! - `compend sim show NAME`: the scene's full description as JSON (a starting point for a
//!   scene of one's own).

use anyhow::Result;
use compend::rig::scene;

#[derive(clap::Args, Debug)]
pub struct Args {
    #[command(subcommand)]
    pub command: SimCommand,
}

#[derive(clap::Subcommand, Debug)]
pub enum SimCommand {
    /// Print the built-in scene names, one per line (easy to impossible).
    List,
    /// Print a built-in scene's full description as JSON.
    Show {
        /// Scene name (see `compend sim list`).
        name: String,
    },
}

pub fn run(args: Args) -> Result<()> {
    match args.command {
        SimCommand::List => {
            for name in scene::BUILTIN {
                println!("{name}");
            }
            Ok(())
        }
        SimCommand::Show { name } => {
            let s = scene::builtin(&name)?;
            println!("{}", serde_json::to_string_pretty(&s)?);
            Ok(())
        }
    }
}
