//! Subcommand implementations: argument structs (clap) and `run` functions.
//! Errors carry context with anyhow; library errors inside decide the exit code.

pub mod bench;
pub mod bench_gpu;
pub mod bench_serve;
pub mod bench_train;
pub mod calibrate;
pub mod cameras;
pub mod compensate;
pub mod eval;
pub mod inspect;
pub mod metrics;
pub mod patterns;
pub mod play;
pub mod pretrain;
pub mod serve;
pub mod show;
pub mod sim;
pub mod train;

/// Exit code for an error chain: the first library error's code (2 = input, 1 = operation),
/// 1 when there is none.
pub fn exit_code(err: &anyhow::Error) -> u8 {
    for cause in err.chain() {
        if let Some(e) = cause.downcast_ref::<compend::Error>() {
            return e.exit_code() as u8;
        }
    }
    1
}

/// A progress bar on stderr, hidden when stderr is not a terminal or JSON output was asked for.
pub fn progress_bar(quiet: bool) -> indicatif::ProgressBar {
    if quiet {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(1);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{msg:>10} [{bar:40}] {pos}/{len} {elapsed} (left {eta})",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    bar
}

/// The setup a command works on: `--setup PATH [--data ROOT]`.
#[derive(clap::Args, Debug)]
pub struct SetupArgs {
    /// The setup folder, holding cam/raw/{ref,train,test,sl} (e.g. ROOT/light2/pos1/curves_np).
    #[arg(long)]
    pub setup: std::path::PathBuf,
    /// The data root holding train/ and test/ [default: the nearest ancestor of the setup that
    /// holds both].
    #[arg(long)]
    pub data: Option<std::path::PathBuf>,
}

impl SetupArgs {
    pub fn open(&self) -> compend::Result<compend::dataset::Setup> {
        compend::dataset::Setup::open(&self.setup, self.data.as_deref())
    }
}
