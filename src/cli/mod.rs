//! Subcommand implementations: argument structs (clap) and `run` functions.
//! Errors carry context with anyhow; library errors inside decide the exit code.

pub mod metrics;
pub mod sim;

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
