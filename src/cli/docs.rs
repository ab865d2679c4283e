//! `compend completions SHELL` and `compend man [COMMAND]`: shell completions (clap_complete)
//! and manual pages (clap_mangen, roff) made from the command line's own definition, so they
//! cannot drift from it. Both go to stdout, for a package or a user to put where their shell
//! or `man` looks (`compend completions bash > /etc/bash_completion.d/compend`, `compend man >
//! /usr/share/man/man1/compend.1`); `compend man --dir DIR` writes every page into a folder,
//! as the Debian package's build does (scripts/package.sh).

use std::io::Write;

use anyhow::{Context, Result};

#[derive(clap::Args, Debug)]
pub struct CompletionsArgs {
    /// The shell to complete for.
    #[arg(value_enum)]
    pub shell: clap_complete::Shell,
}

#[derive(clap::Args, Debug)]
pub struct ManArgs {
    /// The command whose page to write (`calibrate`, `serve`, ...; the page
    /// `compend-COMMAND(1)`) [default: the page of `compend` itself, which lists them all].
    #[arg(conflicts_with = "dir")]
    pub command: Option<String>,
    /// Write the page of `compend` and of every command, as files (`compend.1`,
    /// `compend-calibrate.1`, ...), into this existing folder instead of stdout.
    #[arg(long, value_name = "DIR")]
    pub dir: Option<std::path::PathBuf>,
}

/// Writes the completion script for `args.shell` of the command line `cmd`.
pub fn completions(mut cmd: clap::Command, args: CompletionsArgs) -> Result<()> {
    let name = cmd.get_name().to_string();
    let mut out = Vec::new();
    clap_complete::generate(args.shell, &mut cmd, name, &mut out);
    to_stdout(&out)
}

/// Writes the manual page of `cmd`, or of its subcommand `args.command`; with `args.dir`,
/// every page into that folder.
pub fn man(cmd: clap::Command, args: ManArgs) -> Result<()> {
    if let Some(dir) = &args.dir {
        if !dir.is_dir() {
            return Err(compend::Error::Input(format!(
                "man --dir {}: not a folder (create it first)",
                dir.display()
            ))
            .into());
        }
        let version = cmd.get_version().unwrap_or_default().to_string();
        let cmd = versioned(cmd, &version);
        return clap_mangen::generate_to(cmd, dir)
            .with_context(|| format!("writing the manual pages into {}", dir.display()));
    }
    let cmd = match &args.command {
        None => cmd,
        Some(name) => {
            let name_of = |c: &clap::Command| c.get_name().to_string();
            let found = cmd
                .get_subcommands()
                .find(|c| c.get_name() == name.as_str());
            match found {
                Some(sub) => {
                    let page = format!("{}-{}", cmd.get_name(), sub.get_name());
                    let version = cmd.get_version().unwrap_or_default().to_string();
                    sub.clone().name(page).version(version)
                }
                None => {
                    let known: Vec<String> = cmd.get_subcommands().map(name_of).collect();
                    return Err(compend::Error::Input(format!(
                        "man {name}: no such command; the commands are {}",
                        known.join(", ")
                    ))
                    .into());
                }
            }
        }
    };
    let mut out = Vec::new();
    clap_mangen::Man::new(cmd)
        .render(&mut out)
        .context("rendering the manual page")?;
    to_stdout(&out)
}

/// `cmd` and every command under it with `version` in their pages' footers.
fn versioned(cmd: clap::Command, version: &str) -> clap::Command {
    let subs: Vec<clap::Command> = cmd
        .get_subcommands()
        .map(|s| versioned(s.clone(), version))
        .collect();
    let names: Vec<String> = subs.iter().map(|s| s.get_name().to_string()).collect();
    let mut cmd = cmd.version(version.to_string());
    for (name, sub) in names.iter().zip(subs) {
        cmd = cmd.mut_subcommand(name, |_| sub);
    }
    cmd
}

/// `bytes` to stdout; a reader that has gone (`compend man | head`) is not an error.
fn to_stdout(bytes: &[u8]) -> Result<()> {
    let mut stdout = std::io::stdout().lock();
    match stdout.write_all(bytes).and_then(|()| stdout.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        r => r.context("writing to stdout"),
    }
}
