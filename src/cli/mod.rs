//! Subcommand implementations: argument structs (clap) and `run` functions.
//! Errors carry context with anyhow; library errors inside decide the exit code.

#[cfg(feature = "benches")]
pub mod bench;
#[cfg(feature = "benches")]
pub mod bench_gpu;
#[cfg(feature = "benches")]
pub mod bench_media;
#[cfg(feature = "benches")]
pub mod bench_serve;
#[cfg(feature = "benches")]
pub mod bench_train;
pub mod calibrate;
pub mod cameras;
pub mod compensate;
pub mod docs;
pub mod eval;
pub mod inspect;
pub mod metrics;
pub mod patterns;
pub mod play;
mod play_flags;
mod play_set;
pub mod pretrain;
pub mod progress;
pub mod serve;
pub mod show;
pub mod sim;
pub mod train;

/// An output folder's flag (`flag`) and value (`path`): a folder, or nothing yet (the writer
/// creates it). Anything else there is an input error naming it, found before any work.
pub fn check_out_folder(path: &std::path::Path, flag: &str) -> compend::Result<()> {
    if path.exists() && !path.is_dir() {
        return Err(compend::Error::Input(format!(
            "{flag} {}: not a folder; it takes the folder to write into",
            path.display()
        )));
    }
    Ok(())
}

/// An output folder of the user's (`--out`) that a command writes named files into, listed in a
/// marker file there (`marker`): a later run replaces only files an earlier run listed, and a
/// file of a name it would write that it did not list is an input error naming it.
pub struct OwnedOut {
    dir: std::path::PathBuf,
    marker: std::path::PathBuf,
    /// The command, for the marker's first line and the messages (`compend compensate`).
    command: &'static str,
    listed: std::collections::BTreeSet<String>,
}

impl OwnedOut {
    /// `dir` (given as `flag`), which must be a folder or nothing yet, and the names its marker
    /// `marker` lists.
    pub fn open(
        dir: &std::path::Path,
        flag: &str,
        marker: &str,
        command: &'static str,
    ) -> compend::Result<Self> {
        check_out_folder(dir, flag)?;
        let path = dir.join(marker);
        let listed = match compend::files::read_text(&path, "a list of file names") {
            Ok(text) => text
                .lines()
                .filter(|l| !l.is_empty() && !l.starts_with('#'))
                .map(str::to_string)
                .collect(),
            Err(compend::Error::Missing { .. }) => Default::default(),
            Err(e) => return Err(e),
        };
        Ok(Self {
            dir: dir.to_path_buf(),
            marker: path,
            command,
            listed,
        })
    }

    /// An input error when a file of one of `names` (paths relative to the folder, `/` between
    /// parts) is there and not listed.
    pub fn check(&self, names: &[String]) -> compend::Result<()> {
        match names
            .iter()
            .filter(|n| !self.listed.contains(n.as_str()))
            .map(|n| self.dir.join(n))
            .find(|d| d.symlink_metadata().is_ok())
        {
            Some(dest) => Err(compend::Error::Input(format!(
                "{}: already there, and not written by `{}` (not listed in {}), so it is not \
                 replaced: choose another --out (or, if an older compend wrote it, remove it)",
                dest.display(),
                self.command,
                self.marker.display()
            ))),
            None => Ok(()),
        }
    }

    /// Lists `names` beside those listed before, creating the folder: before they are written,
    /// so that a run stopped half-way may be run again.
    pub fn claim(&mut self, names: &[String]) -> compend::Result<()> {
        std::fs::create_dir_all(&self.dir)
            .map_err(|e| compend::Error::io(&self.dir, "create folder", e))?;
        self.listed.extend(names.iter().cloned());
        let list: String = std::iter::once(format!("# files written by `{}`", self.command))
            .chain(self.listed.iter().cloned())
            .map(|l| l + "\n")
            .collect();
        compend::files::write_atomically(&self.marker, list.as_bytes())
    }
}

/// Where `path` leads once made: the deepest part of it that exists with its links and `..`
/// resolved (`canonicalize`), then the rest as written, a `..` there taking off the part before
/// it (as `create_dir_all` would make it).
pub fn resolved(path: &std::path::Path) -> std::io::Result<std::path::PathBuf> {
    use std::path::Component;
    let absolute = std::path::absolute(path)?;
    let parts: Vec<Component> = absolute.components().collect();
    let mut k = parts.len();
    let mut base = std::path::PathBuf::new();
    while k > 0 {
        let prefix: std::path::PathBuf = parts[..k].iter().collect();
        if let Ok(real) = prefix.canonicalize() {
            base = real;
            break;
        }
        k -= 1;
    }
    for part in &parts[k..] {
        match part {
            Component::ParentDir => {
                base.pop();
            }
            Component::CurDir => {}
            other => base.push(other),
        }
    }
    Ok(base)
}

/// The lock of the state directory a model goes into (`out`'s folder holds a `compend.lock`:
/// a service's state, whose model path is `STATE/model`), held by `holder` for as long as it is
/// kept, unless `held` is that folder already (locked by this process). A running service
/// there is an input error naming it; `None` when there is no such lock file.
pub fn lock_model_state(
    out: &std::path::Path,
    held: &[&std::path::Path],
    holder: &str,
) -> compend::Result<Option<std::fs::File>> {
    let Some(state) = out.parent().filter(|p| p.join("compend.lock").is_file()) else {
        return Ok(None);
    };
    let same = |a: &&std::path::Path| a.canonicalize().ok() == state.canonicalize().ok();
    if held.iter().any(same) {
        return Ok(None);
    }
    compend::service::lock_state_if_held(state, holder)
}

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

/// `--refresh-hz HZ` checked before any work (`train`, `bench`, `calibrate`): the rate `auto`'s
/// climb is weighed at; `None` when not asked or 0. `auto`: whether the command runs `auto`, the
/// only method that weighs a climb; `otherwise`: what the error says when it does not.
pub fn refresh_rate(hz: Option<f64>, auto: bool, otherwise: &str) -> compend::Result<Option<f64>> {
    let Some(hz) = hz else {
        return Ok(None);
    };
    if let Some(problem) = compend::fit::refresh_rate_problem(hz) {
        return Err(compend::Error::Input(format!("--refresh-hz {problem}")));
    }
    if hz == 0.0 {
        return Ok(None);
    }
    if !auto {
        return Err(compend::Error::Input(format!(
            "--refresh-hz {hz}: only `auto` weighs a climb's live pass; {otherwise}"
        )));
    }
    Ok(Some(hz))
}

/// The timer of `--refresh-hz HZ` (`train`, `bench`): `auto`'s climb weighed on this machine's
/// GPU for a display refreshing at `hz`, checked ([`refresh_rate`]) before any work.
pub fn refresh_timer(
    hz: Option<f64>,
    auto: bool,
    otherwise: &str,
) -> anyhow::Result<Option<std::sync::Arc<dyn compend::fit::LivePass>>> {
    use anyhow::Context as _;
    let Some(hz) = refresh_rate(hz, auto, otherwise)? else {
        return Ok(None);
    };
    let ctx = compend::gpu::GpuContext::new().with_context(|| {
        format!("--refresh-hz {hz}: opening this machine's GPU to time the climb's live pass")
    })?;
    Ok(Some(std::sync::Arc::new(
        compend::gpu::live::GpuLivePass::new(ctx, hz)?,
    )))
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

/// How a CompenNet++ rung trains, as `train` and `bench` take it: `--iters`, `--batch`,
/// `--device`. (`calibrate` takes its own: its defaults come from the configuration's
/// `[calibration]`, which has no batch size, and `auto`'s climb has `--climb-iters`.)
#[derive(clap::Args, Debug, Clone)]
pub struct NetworkFlags {
    /// CompenNet++ rungs (and the one `auto` climbs to): iterations instead of the rung's (the
    /// lr step scales with it).
    #[arg(long)]
    pub iters: Option<usize>,
    /// CompenNet++ rungs (and the one `auto` climbs to): batch size instead of the rung's.
    #[arg(long)]
    pub batch: Option<usize>,
    /// CompenNet++ rungs: where to train, `cpu`, `cuda` or `cuda:N` (an NVIDIA GPU; needs a
    /// build with `--features cuda`); with `--method auto` it also chooses the rung climbed to
    /// (compennet++-res on the CPU, compennet++-res-full on a GPU). The `linear` rungs always
    /// fit on the CPU.
    #[arg(long, default_value = "cpu")]
    pub device: compend::fit::TrainDevice,
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

/// The projector size a model plays at without a window (`play --no-window`, `compensate` of a
/// film, `bench-media`): `given` (`--projector`), else the extent of the canvas the model
/// records, else the projector size its calibration's captures record; an input error asking
/// for `--projector` when none is known.
pub fn model_projector(
    model: &compend::model::Model,
    given: Option<compend::raster::ImageSize>,
) -> compend::Result<compend::raster::ImageSize> {
    if let Some(p) = given {
        return Ok(p);
    }
    if let Some(c) = model.meta.canvas {
        return Ok(compend::raster::ImageSize::new(
            c.x + c.width,
            c.y + c.height,
        ));
    }
    if let Some(setup) = model.meta.training.setup.as_deref()
        && let Ok(Some(p)) = compend::dataset::manifest::recorded_projector(setup)
    {
        return Ok(p);
    }
    Err(compend::Error::Input(format!(
        "the model ({}) records no projector size (it was trained on recorded data, or its \
         calibration's captures are gone): give --projector WxH",
        model.meta.method
    )))
}
