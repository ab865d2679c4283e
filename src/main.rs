//! The `compend` command line. Each subcommand lives in `src/cli/<name>.rs`.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// mimalloc: CompenNet++ training allocates and frees tensors of tens to hundreds of MB every
/// step, which glibc's allocator maps and unmaps each time (page faults were 10 % of a training
/// profile). See [`keep_freed_memory`].
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// mimalloc's `mi_option_purge_delay` (its `mimalloc.h`, v2 and v3; not named by
/// libmimalloc-sys): milliseconds before freed memory is returned to the OS, -1 for never.
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

/// For the training commands: freed memory stays with the process for reuse instead of going
/// back to the OS after a delay (1 s by default), so the next step's tensors come without page faults. The process
/// then keeps its peak memory until it exits; playback does not call this.
fn keep_freed_memory() {
    // SAFETY: mi_option_set only stores an option value; any option id and value are valid.
    unsafe { libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, -1) }
}

mod cli;

/// The build's features in words, for `VERSION`.
#[cfg(all(feature = "cuda", feature = "benches"))]
macro_rules! features {
    () => {
        "cuda, benches"
    };
}
#[cfg(all(feature = "cuda", not(feature = "benches")))]
macro_rules! features {
    () => {
        "cuda"
    };
}
#[cfg(all(not(feature = "cuda"), feature = "benches"))]
macro_rules! features {
    () => {
        "benches; CPU training only"
    };
}
#[cfg(all(not(feature = "cuda"), not(feature = "benches")))]
macro_rules! features {
    () => {
        "none, CPU training only"
    };
}

/// `compend --version`: the package version, the commit it was built from (`build.rs`) and
/// the build's features (CUDA training, the benchmarks).
const VERSION: &str = concat!(
    env!("CARGO_PKG_VERSION"),
    " (commit ",
    env!("COMPEND_COMMIT"),
    "; features: ",
    features!(),
    ")"
);

#[derive(Parser, Debug)]
#[command(name = "compend", version = VERSION, about = "Projector-camera compensation: make a projector look right on any surface", long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// In `--help`, the commands a user needs first (calibrate and the service's), then the rig's
/// and the data's tools; the benchmarks last, in a build with the `benches` feature only.
#[derive(Subcommand, Debug)]
enum Command {
    /// Calibrate a rig: measure its latency, project and capture the patterns, train, verify
    /// on held-out images and install the model only if it verified.
    Calibrate(cli::calibrate::Args),
    /// The service: calibrate when needed, play compensated video, answer the control socket.
    Serve(cli::serve::ServeArgs),
    /// The running service's state, model, source, frame counts and monitoring.
    Status(cli::serve::StatusArgs),
    /// Live compensation of a video source on the projector window or the virtual rig; without
    /// --model, asks the running service to play the source.
    Play(cli::play::Args),
    /// Pause the service's playback: a film or stream holds its frame (`play` resumes it),
    /// anything else stops (the projector shows black).
    Pause(cli::serve::ClientArgs),
    /// The service's playlist: the next item.
    Next(cli::serve::ClientArgs),
    /// The service's playlist: the previous item.
    Previous(cli::serve::ClientArgs),
    /// The service's film: go to a time from its start.
    Seek(cli::serve::SeekArgs),
    /// Ask the running service to calibrate again (install only if the new model verifies).
    Recalibrate(cli::serve::RecalibrateArgs),
    /// Stop the running service.
    Stop(cli::serve::ClientArgs),
    /// Send one raw request line to the service and print its JSON reply.
    Ctl(cli::serve::CtlArgs),
    /// The configuration file: `compend config check FILE`.
    Config(cli::serve::ConfigArgs),
    /// List the cameras (V4L2 devices): formats, sizes, frame rates and controls.
    Cameras(cli::cameras::Args),
    /// Show a projector-space PNG on the projector window.
    Show(cli::show::Args),
    /// Write the projector-side dataset images: sampling images (train/, test/), colour cube and
    /// gray image (ref/), Gray-code structured light (sl/).
    Patterns(cli::patterns::Args),
    /// Fit a compensation model on a setup's training pairs and write the model directory.
    Train(cli::train::Args),
    /// Score a model on a setup's test pairs (paper protocol), with the uncompensated row and,
    /// for a linear rung, its prediction of each capture in camera space.
    Eval(cli::eval::Args),
    /// Compensation images for desired camera-view images, with a trained model.
    Compensate(cli::compensate::Args),
    /// Check a dataset setup (every image of every set) and print its summary.
    Inspect(cli::inspect::Args),
    /// PSNR, RMSE and SSIM (paper conventions) of two PNGs or two folders of same-named PNGs.
    Metrics(cli::metrics::Args),
    /// The virtual rig: simulated projector-camera scenes (list, show, export, sheet, score).
    Sim(cli::sim::Args),
    /// Shell completions: `compend completions bash > /etc/bash_completion.d/compend` (also
    /// zsh, fish, elvish, powershell).
    Completions(cli::docs::CompletionsArgs),
    /// The manual page of compend, or of one of its commands, in roff on stdout: `compend man
    /// > compend.1`, `compend man calibrate > compend-calibrate.1`.
    Man(cli::docs::ManArgs),
    /// Pre-train CompenNet's photometric weights on synthetic pairs (no setup, no projection):
    /// how the shipped `weights/compennet-pretrain-w*.safetensors` were made.
    Pretrain(cli::pretrain::Args),
    /// Benchmark methods × scenes × training-set sizes × seeds on the virtual rig.
    #[cfg(feature = "benches")]
    Bench(cli::bench::Args),
    /// Per-frame GPU time of the compensation pass against a plain texture copy, and frames
    /// dropped at 60 Hz on the virtual rig and by the pipeline alone.
    #[cfg(feature = "benches")]
    BenchGpu(cli::bench_gpu::Args),
    /// Films through compend on this machine: decode cost, live playback of a film through the
    /// pass (frames dropped, latency, CPU), offline compensation's speed, and the sound's
    /// offset from the picture on the virtual rig.
    #[cfg(feature = "benches")]
    BenchMedia(cli::bench_media::Args),
    /// The service's targets on the virtual rig, driven through its socket: status while
    /// training, a flood of malformed requests, drops during model swaps, drift detection.
    #[cfg(feature = "benches")]
    BenchServe(cli::bench_serve::Args),
    /// Training and inference cost of the CompenNet++ rungs and `linear` on this CPU, against
    /// the machine's arithmetic rate measured in the same run.
    #[cfg(feature = "benches")]
    BenchTrain(cli::bench_train::Args),
}

/// Runs `f` on a worker thread of rayon's global pool (the pool candle's matrix products and
/// compend's own parallel ops use) and waits for it. A training step runs hundreds of parallel
/// ops; called from the main thread, each one is injected into the pool and the main thread
/// sleeps until a worker wakes it: two thread switches per op, which cost more than the op at
/// the CPU rung's sizes and far more when the host is busy. From a worker, an op splits its work
/// with the other workers directly.
fn on_a_pool_worker<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    rayon::scope(|_| f())
}

/// candle 0.11 runs element-wise ops of 64 Ki elements or more on a thread pool of its own
/// (`CANDLE_NUM_THREADS` − 1 threads beside the caller; by default one per core), whose threads
/// spin for up to 25 000 PAUSEs after every op before they sleep. The compute commands already
/// keep every core busy through rayon (a training step's shards, split matrix products), so
/// those threads only take cores from it: on 2 cores the CPU rung's training step ran about
/// twice as slow with them. Unless the user set `CANDLE_NUM_THREADS`, it is set to 1 (no extra
/// threads: such ops run on the calling thread). Must run before any thread is started.
fn no_candle_side_pool() {
    if std::env::var_os("CANDLE_NUM_THREADS").is_none() {
        // SAFETY: called at the start of `main`, before any other thread exists.
        unsafe { std::env::set_var("CANDLE_NUM_THREADS", "1") };
    }
}

/// Mesa's Vulkan device-select layer (an implicit layer of `mesa-vulkan-drivers`) asks the
/// Wayland compositor for the default GPU each time a Vulkan instance lists its devices; with no
/// `$XDG_RUNTIME_DIR` (a system service, a test, ssh) libwayland then prints "error:
/// XDG_RUNTIME_DIR is invalid or not set in the environment." twice per command that opens the
/// GPU, though nothing is wrong and no compositor could be reached. There it is switched off
/// (`NODEVICE_SELECT=1`, its own switch): compend chooses its adapter itself, by wgpu's power
/// preference. Unless the user set `NODEVICE_SELECT`. Must run before any thread is started.
fn no_wayland_device_probe() {
    if std::env::var_os("XDG_RUNTIME_DIR").is_none()
        && std::env::var_os("NODEVICE_SELECT").is_none()
    {
        // SAFETY: called at the start of `main`, before any other thread exists.
        unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
    }
}

/// `println!` (and `eprintln!`) panics when stdout (stderr) is a pipe whose reader has gone
/// (`compend sim list | head -1`, `play --json | true`): the panic is turned into a quiet exit
/// with status 0, as the output has nowhere to go; every other panic is reported as before. Rust ignores `SIGPIPE`, and
/// compend keeps it so: its clients write to sockets, where a closed peer must be an error
/// rather than a silent death.
fn quiet_on_broken_stdout() {
    let report = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let text = info
            .payload()
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| info.payload().downcast_ref::<&str>().copied())
            .unwrap_or("");
        let printing = text.starts_with("failed printing to stdout")
            || text.starts_with("failed printing to stderr");
        if printing && text.contains("Broken pipe") {
            std::process::exit(0);
        }
        report(info)
    }));
}

/// Log lines (warnings about accepted-but-suspect input, progress of long operations) go to
/// stderr as plain text. The level comes from `COMPEND_LOG` (tracing's filter syntax, e.g.
/// `info` or `compend=debug`), `warn` by default.
///
/// The service (`serve`) logs at `info` by default (its startup line, the periodic frame counts,
/// monitoring); under systemd (`$JOURNAL_STREAM` names our stderr) it writes to the journal
/// natively, with the levels as journal priorities.
fn init_logging(service: bool) {
    let default = if service { "info" } else { "warn" };
    let filter = tracing_subscriber::EnvFilter::try_from_env("COMPEND_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    if service && stderr_is_journal() {
        use tracing_subscriber::layer::SubscriberExt;
        use tracing_subscriber::util::SubscriberInitExt;
        if let Ok(journal) = tracing_journald::layer() {
            let _ = tracing_subscriber::registry()
                .with(filter)
                .with(journal.with_syslog_identifier("compend".into()))
                .try_init();
            return;
        }
    }
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_target(false)
        .without_time()
        .with_ansi(false)
        // A line that cannot be written (the log's disk full, the reader gone) is lost, and
        // nothing else: by default the subscriber reports it with `eprintln!` to the same
        // stderr, which panics when that write fails too, and the service died with it.
        .log_internal_errors(false)
        .try_init();
}

/// Whether stderr is connected to the journal: systemd sets `$JOURNAL_STREAM` to the
/// `device:inode` of the stream it gave the service.
fn stderr_is_journal() -> bool {
    use std::os::unix::fs::MetadataExt;
    let Some(v) = std::env::var_os("JOURNAL_STREAM") else {
        return false;
    };
    let Some((dev, ino)) = v.to_str().and_then(|s| s.split_once(':')) else {
        return false;
    };
    let Ok(meta) = std::fs::metadata("/proc/self/fd/2") else {
        return false;
    };
    dev.parse() == Ok(meta.dev()) && ino.parse() == Ok(meta.ino())
}

/// The error and its causes on one line, each cause once: library errors already name their
/// cause in their message (an I/O error's OS reason, say), so a cause whose text is already
/// there is not repeated.
fn error_chain(err: &anyhow::Error) -> String {
    let mut line = err.to_string();
    for cause in err.chain().skip(1) {
        let text = cause.to_string();
        if !line.contains(&text) {
            line.push_str(": ");
            line.push_str(&text);
        }
    }
    line
}

fn main() -> ExitCode {
    no_wayland_device_probe();
    quiet_on_broken_stdout();
    let args = Cli::parse();
    init_logging(matches!(args.command, Command::Serve(_)));
    let compute = match args.command {
        Command::Calibrate(_) | Command::Pretrain(_) | Command::Train(_) => true,
        #[cfg(feature = "benches")]
        Command::Bench(_) | Command::BenchTrain(_) => true,
        _ => false,
    };
    if compute {
        no_candle_side_pool();
        keep_freed_memory();
    }
    if matches!(args.command, Command::Serve(_)) {
        // The service trains too, but runs for months: freed memory goes back to the OS.
        no_candle_side_pool();
    }
    let dispatch = move || match args.command {
        #[cfg(feature = "benches")]
        Command::Bench(a) => cli::bench::run(a),
        #[cfg(feature = "benches")]
        Command::BenchGpu(a) => cli::bench_gpu::run(a),
        #[cfg(feature = "benches")]
        Command::BenchMedia(a) => cli::bench_media::run(a),
        #[cfg(feature = "benches")]
        Command::BenchServe(a) => cli::bench_serve::run(a),
        #[cfg(feature = "benches")]
        Command::BenchTrain(a) => cli::bench_train::run(a),
        Command::Cameras(a) => cli::cameras::run(a),
        Command::Calibrate(a) => cli::calibrate::run(a),
        Command::Compensate(a) => cli::compensate::run(a),
        Command::Completions(a) => {
            use clap::CommandFactory;
            cli::docs::completions(Cli::command(), a)
        }
        Command::Man(a) => {
            use clap::CommandFactory;
            cli::docs::man(Cli::command(), a)
        }
        Command::Config(a) => cli::serve::config(a),
        Command::Ctl(a) => cli::serve::ctl(a),
        Command::Eval(a) => cli::eval::run(a),
        Command::Inspect(a) => cli::inspect::run(a),
        Command::Metrics(a) => cli::metrics::run(a),
        Command::Patterns(a) => cli::patterns::run(a),
        Command::Pause(a) => cli::serve::simple(&a, compend::service::protocol::Request::Pause),
        Command::Next(a) => cli::serve::simple(&a, compend::service::protocol::Request::Next),
        Command::Previous(a) => {
            cli::serve::simple(&a, compend::service::protocol::Request::Previous)
        }
        Command::Seek(a) => cli::serve::simple(
            &a.client,
            compend::service::protocol::Request::Seek {
                position_s: a.position_s,
            },
        ),
        Command::Play(a) => cli::play::run(a),
        Command::Pretrain(a) => cli::pretrain::run(a),
        Command::Recalibrate(a) => cli::serve::recalibrate(a),
        Command::Serve(a) => cli::serve::serve(a),
        Command::Status(a) => cli::serve::status(a),
        Command::Stop(a) => cli::serve::simple(&a, compend::service::protocol::Request::Stop),
        Command::Train(a) => cli::train::run(a),
        Command::Show(a) => cli::show::run(a),
        Command::Sim(a) => cli::sim::run(a),
    };
    let result = if compute {
        on_a_pool_worker(dispatch)
    } else {
        dispatch()
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("compend: error: {}", error_chain(&err));
            ExitCode::from(cli::exit_code(&err))
        }
    }
}

#[cfg(test)]
mod tests {
    /// clap's own consistency checks over every subcommand (unique names, valid conflicts and
    /// requirements), which otherwise run only when a command is parsed in a debug build.
    #[test]
    fn the_command_line_is_consistent() {
        use clap::CommandFactory;
        super::Cli::command().debug_assert();
    }

    /// The option id is mimalloc's purge delay: the bundled mimalloc (v3) defaults it to 1 000 ms.
    #[test]
    fn compute_commands_run_on_a_pool_worker() {
        assert_eq!(rayon::current_thread_index(), None);
        let index = super::on_a_pool_worker(rayon::current_thread_index);
        assert!(index.is_some_and(|i| i < rayon::current_num_threads()));
    }

    #[test]
    fn purge_delay_option_is_the_one_set() {
        // SAFETY: mi_option_get only reads an option value.
        let delay = unsafe { libmimalloc_sys::mi_option_get(super::MI_OPTION_PURGE_DELAY) };
        assert_eq!(delay, 1000);
    }
}
