//! `compend compensate`: compensation images for desired camera-view images, or a compensated
//! film for a film (the projector canvas of every frame, encoded, with the film's timing).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use compend::model::Model;
use compend::pngio;
use compend::raster::Camera;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The model directory.
    #[arg(long)]
    pub model: PathBuf,
    /// A desired camera-view PNG, or a folder of them (e.g. SETUP/cam/desire/test); or a
    /// film (a video file: MP4, MKV, MOV, WebM, ...), compensated frame by frame as `play`
    /// would show it.
    #[arg(long)]
    pub input: PathBuf,
    /// Folder for the network-space compensation PNGs (same file names as the inputs), e.g.
    /// SETUP/prj/cmp/test/MODEL. A file already there is replaced only when an earlier
    /// `compensate` wrote it (they are listed in the folder's `.compend-compensated`); never the
    /// inputs. For a film: the compensated video file (.mp4, .mov, .mkv, .webm), never over a
    /// file that is there.
    #[arg(long)]
    pub out: PathBuf,
    /// For a film: the projector's size, WxH [default: the one the model's calibration
    /// placed its canvas on].
    #[arg(long, value_name = "WxH")]
    pub projector: Option<String>,
}

/// The list `compensate` keeps in its output folder of the images it wrote there, one name a
/// line after a header: a later run may replace those, and nothing else.
const MARKER: &str = ".compend-compensated";

pub fn run(args: Args) -> Result<()> {
    if let Some(film) = film_input(&args.input) {
        return compensate_film(&args, film);
    }
    if args.projector.is_some() {
        return Err(compend::Error::Input(
            "--projector is for a film; compensation images are network-size".into(),
        )
        .into());
    }
    let model = Model::load(&args.model)?;
    let inputs = list_inputs(&args.input)?;
    // Names kept as they are (the list holds one per line): an input named otherwise is refused.
    let names: Vec<String> = inputs
        .iter()
        .map(|p| match p.file_name().and_then(|n| n.to_str()) {
            Some(n) if !n.contains('\n') => Ok(n.to_string()),
            _ => Err(compend::Error::Input(format!(
                "{}: a name that is not UTF-8 text on one line; rename it to compensate it",
                p.display()
            ))),
        })
        .collect::<compend::Result<_>>()?;
    let mut out = check_out(&args.out, &inputs)?;
    out.check(&names)?;
    out.claim(&names)?;
    for path in &inputs {
        let img =
            pngio::read_rgb_sized::<Camera>(path, model.camera_size(), "the model's camera size")?;
        let out = model.infer(&img)?;
        let name = path.file_name().context("input has a file name")?;
        let dest = args.out.join(name);
        pngio::write_rgb(&dest, &out).with_context(|| format!("writing {}", dest.display()))?;
    }
    eprintln!(
        "wrote {} compensation image(s) to {}",
        inputs.len(),
        args.out.display()
    );
    Ok(())
}

/// Whether `out` may take the compensation images of `inputs`: a folder (or nothing yet), not
/// the one the inputs are in, where a file of one of their names is there only if an earlier
/// `compensate` wrote it ([`MARKER`]). Returns the folder with the names its marker lists.
/// Input errors name the path.
fn check_out(out: &Path, inputs: &[PathBuf]) -> Result<super::OwnedOut> {
    super::check_out_folder(out, "--out")?;
    let here = out.canonicalize().ok();
    if let Some(p) = inputs.iter().find(|p| {
        let dir = p.parent().map(|d| {
            if d.as_os_str().is_empty() {
                Path::new(".")
            } else {
                d
            }
        });
        here.is_some() && dir.and_then(|d| d.canonicalize().ok()) == here
    }) {
        return Err(compend::Error::Input(format!(
            "{}: the folder of the input {}; the compensation images would replace the inputs: \
             choose another --out",
            out.display(),
            p.display()
        ))
        .into());
    }
    Ok(super::OwnedOut::open(
        out,
        "--out",
        MARKER,
        "compend compensate",
    )?)
}

fn list_inputs(input: &Path) -> Result<Vec<PathBuf>> {
    if input.is_file() {
        return Ok(vec![input.to_path_buf()]);
    }
    if !input.is_dir() {
        return Err(compend::Error::Missing {
            path: input.to_path_buf(),
            expected: "a PNG file or a folder of PNGs".into(),
        }
        .into());
    }
    let mut out: Vec<PathBuf> = std::fs::read_dir(input)
        .map_err(|e| compend::Error::io(input, "list folder", e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")))
        .collect();
    // A name of an image that is no image (a folder, a FIFO, a broken link) is not skipped
    // quietly.
    if let Some(odd) = out.iter().find(|p| !p.is_file()) {
        return Err(compend::Error::Input(format!(
            "{}: not a regular file (a folder, a FIFO, a device or a broken link), in the input \
             folder of images",
            odd.display()
        ))
        .into());
    }
    out.sort();
    if out.is_empty() {
        return Err(compend::Error::Input(format!(
            "{}: no PNG files in this folder",
            input.display()
        ))
        .into());
    }
    Ok(out)
}

/// The film `input` names: a file with a video file's ending.
fn film_input(input: &Path) -> Option<compend::source::MediaSpec> {
    let ext = input.extension()?.to_str()?.to_ascii_lowercase();
    compend::source::spec::VIDEO_EXTENSIONS
        .contains(&ext.as_str())
        .then(|| compend::source::MediaSpec::File(input.to_path_buf()))
}

/// A film through the model, frame by frame, offline (every frame, as fast as it goes), to an
/// encoded file at the film's frame rate; the same pass and placement as `play`.
fn compensate_film(args: &Args, film: compend::source::MediaSpec) -> Result<()> {
    use compend::output::{MediaOutput, OutputSpec, Teed};
    use compend::player::{Headless, Player};
    use compend::source::{self, AudioOut, FeedMode, SourceSpec};
    let out = OutputSpec::parse(&format!("file:{}", args.out.display()))?;
    let projector = args
        .projector
        .as_deref()
        .map(|s| compend::raster::ImageSize::parse(s, false).map_err(compend::Error::Input))
        .transpose()?;
    let model = Model::load(&args.model)?;
    let size = super::model_projector(&model, projector)?;
    let probe = source::media::probe(&film, source::MEDIA_CHECK_TIMEOUT)?;
    let fps = match probe.fps {
        Some(f) => f,
        None => {
            eprintln!("compensate: the film declares no frame rate; writing it at 30 fps");
            30.0
        }
    };
    let no_sound = AudioOut {
        sink: None,
        delay_ms: 0.0,
    };
    let source = source::open_with(&SourceSpec::Media(film), &no_sound)?;
    let ctx = compend::gpu::GpuContext::new()?;
    let mut player = Player::start(
        &ctx,
        &model,
        size,
        model.display_range(),
        source,
        FeedMode::Queue,
    )?;
    let output = MediaOutput::start(&out, size, fps, false)?;
    eprintln!(
        "compensate: {} ({}) to {} at {size}, {fps:.3} fps, with {}",
        player.feed.describe(),
        probe
            .duration_s
            .map_or("length unknown".to_string(), |d| format!("{d:.1} s")),
        args.out.display(),
        ctx.describe()
    );
    let mut screen = Headless::new(&ctx, fps);
    let stats = player.run(&mut Teed::new(&mut screen, output), None)?;
    let film_s = stats.shown as f64 / fps;
    eprintln!(
        "compensate: {} frames ({film_s:.1} s of film) in {:.1} s: {:.2}x real time; wrote {}",
        stats.output_frames.unwrap_or(0),
        stats.seconds,
        film_s / stats.seconds.max(1e-9),
        args.out.display()
    );
    Ok(())
}
