//! Subcommand implementations: argument structs (clap) and `run` functions.
//! Errors carry context with anyhow; library errors inside decide the exit code.

pub mod bench;
pub mod compensate;
pub mod eval;
pub mod inspect;
pub mod metrics;
pub mod patterns;
pub mod sim;
pub mod train;

/// Exit code for an error chain: the first library error's code (2 = input, 1 = operation),
/// 2 for an I/O error on a user-named path, 1 otherwise.
pub fn exit_code(err: &anyhow::Error) -> u8 {
    for cause in err.chain() {
        if let Some(e) = cause.downcast_ref::<compend::Error>() {
            return e.exit_code() as u8;
        }
        if cause.downcast_ref::<InputError>().is_some() {
            return 2;
        }
    }
    1
}

/// A usage error found by a subcommand after parsing (e.g. two arguments that do not fit).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct InputError(pub String);

/// A progress bar on stderr, hidden when stderr is not a terminal or JSON output was asked for.
pub fn progress_bar(quiet: bool) -> indicatif::ProgressBar {
    if quiet {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(1);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg:>10} [{bar:40}] {pos}/{len} {elapsed}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar
}
