//! `compend sim ...`: the virtual rig from the command line.
//!
//! - `compend sim list`: the built-in scene names, one per line (easy to impossible), then the
//!   built-in sets of projectors (`tiled`, `stacked`).
//! - `compend sim show NAME`: a scene's full description as JSON (edit it and pass the file as
//!   `--scene` to simulate a scene of one's own).
//! - `compend sim export --scene NAME --out ROOT`: a complete setup in the dataset layout:
//!   projector-side images (as `compend patterns` writes them) and `ROOT/<scene>/` with
//!   reference, structured-light, training and test captures, desired test images in the
//!   displayable area, and `rig.json`.
//! - `compend sim sheet --out DIR`: a contact sheet PNG per scene.
//! - `compend sim score --setup SETUP`: closed-loop scores on the rig of every model's
//!   compensation images (`prj/cmp/test/<model>`), next to the uncompensated, geometry-only and
//!   oracle rows, as gaps to the oracle (the scene's physical ceiling).
//! - `compend sim set-score --model DIR --data DATA`: a set of projectors' joint model in
//!   closed loop on the views its calibration verified, against the set's physical ceiling and
//!   each projector alone, with the seam figures and the unreachable shares.

use std::path::PathBuf;

use anyhow::{Context, Result};
use compend::dataset::DataRoot;
use compend::patterns::{self, Set};
use compend::rig::{self, ExportOptions, Phase, Simulator, scene};

use super::patterns::parse_wxh;
use compend::raster::ImageSize;

#[derive(clap::Args, Debug)]
pub struct Args {
    #[command(subcommand)]
    pub command: SimCommand,
}

#[derive(clap::Subcommand, Debug)]
pub enum SimCommand {
    /// Print the built-in scene names, one per line (easy to impossible).
    List,
    /// Print a scene's full description as JSON.
    Show {
        /// Built-in scene name (see `compend sim list`) or scene JSON file.
        name: String,
    },
    /// Write a complete simulated setup in the dataset layout.
    Export(ExportArgs),
    /// Write a contact sheet PNG per scene: surface, a capture, desired, uncompensated, oracle.
    Sheet(SheetArgs),
    /// Closed-loop scores of compensation images on the rig of an exported setup, with the
    /// uncompensated, geometry-only and oracle rows.
    Score(ScoreArgs),
    /// Closed-loop scores of a set of projectors' joint model (from `calibrate --rig
    /// virtual:SET`) against the set's physical ceiling, each projector alone, the seam figures
    /// and the unreachable shares.
    SetScore(SetScoreArgs),
}

#[derive(clap::Args, Debug)]
pub struct SetScoreArgs {
    /// The set's model directory (`set.json`, `projector-N/`).
    #[arg(long)]
    pub model: PathBuf,
    /// The calibration's data folder: its set verification's desired views
    /// (`set/desired-NNN.png`) are scored.
    #[arg(long)]
    pub data: PathBuf,
    /// Score only the first N views (the ceiling costs a few seconds per view at 640x480).
    #[arg(long)]
    pub ntest: Option<usize>,
    /// Oracle solver iterations.
    #[arg(long, default_value_t = rig::OracleOptions::default().iterations)]
    pub oracle_iterations: usize,
    /// Print one JSON object on stdout instead of the lines.
    #[arg(long)]
    pub json: bool,
}

#[derive(clap::Args, Debug)]
pub struct ScoreArgs {
    #[command(flatten)]
    pub setup: super::SetupArgs,
    /// Models to score (folders under SETUP/prj/cmp/test); default: all of them.
    #[arg(long)]
    pub model: Vec<String>,
    /// Score only the first N test images (the oracle costs a few seconds per image at
    /// 640x480).
    #[arg(long)]
    pub ntest: Option<usize>,
    /// Score with the projector where it was at calibration, even for a scene with drift (by
    /// default the drift scene is scored after its projector moved).
    #[arg(long)]
    pub no_drift: bool,
    /// Oracle solver iterations.
    #[arg(long, default_value_t = rig::OracleOptions::default().iterations)]
    pub oracle_iterations: usize,
    /// Frames averaged per capture, each with its own camera noise (`compend calibrate
    /// --average`'s default is 3): with the same count as the calibration, `sim score` sees the
    /// surface through as much noise as the calibration's verification did.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=64))]
    pub average: u64,
    /// Print one JSON object on stdout instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Write what the camera sees in the displayable area for every row, next to the desired
    /// image: OUT/desired/img_NNNN.png and OUT/<row>/img_NNNN.png (camera pixels, 8-bit sRGB).
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
}

/// Scene, seed and resolution options shared by `export` and `sheet`.
#[derive(clap::Args, Debug)]
pub struct SceneArgs {
    /// Seed of the scene's texture, the camera noise and the sampling images.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Camera resolution WxH (default: the scene's, 640x480 for built-in scenes).
    #[arg(long, value_name = "WxH", value_parser = parse_size)]
    pub camera: Option<ImageSize>,
    /// Projector resolution WxH (default: the scene's, 800x600 for built-in scenes).
    #[arg(long, value_name = "WxH", value_parser = parse_size)]
    pub projector: Option<ImageSize>,
    /// Network size of the sampling and test images: N (square) or WxH, sides divisible by 4.
    #[arg(long, default_value = "256", value_name = "N|WxH", value_parser = parse_network)]
    pub network: ImageSize,
}

#[derive(clap::Args, Debug)]
pub struct ExportArgs {
    /// Built-in scene name (see `compend sim list`) or scene JSON file.
    #[arg(long)]
    pub scene: String,
    /// Data root to write (created as needed; files of the same name are replaced).
    #[arg(long)]
    pub out: PathBuf,
    /// Training images to write and capture.
    #[arg(long, default_value_t = 500, value_parser = clap::value_parser!(u64).range(1..=9999))]
    pub ntrain: u64,
    /// Test images to write and capture (each with its desired image).
    #[arg(long, default_value_t = 200, value_parser = clap::value_parser!(u64).range(1..=9999))]
    pub ntest: u64,
    #[command(flatten)]
    pub scene_args: SceneArgs,
    /// Setup folder under the root (default: the scene name).
    #[arg(long)]
    pub setup: Option<PathBuf>,
    /// Capture only black, white and gray references instead of the whole colour cube.
    #[arg(long)]
    pub no_cube: bool,
    /// Capture the setup with the projector moved (the drift scene's pose after calibration).
    #[arg(long)]
    pub drifted: bool,
    /// Intensity of the desired images: `reachable` scales the test images into the range the
    /// projector can show across the displayable area (so the oracle measures compensation, not
    /// clipping); `full` places them unscaled.
    #[arg(long, value_enum, default_value_t = DesiredRange::Reachable)]
    pub desired_range: DesiredRange,
    /// Capture as `compend calibrate` did for this model directory: the virtual camera at the
    /// model's recorded exposure (a factor of the scene's) and the desired images scaled into
    /// the display range calibrate found (instead of --desired-range), so that `sim score` of
    /// the model's compensation images asks of it what calibrate's verification asked.
    #[arg(long, value_name = "MODEL", conflicts_with = "desired_range")]
    pub as_calibrated: Option<PathBuf>,
    /// Closed-loop pairs, as `compend calibrate` takes them: `linear` fitted on the exported
    /// training pairs compensates N sampling images placed as desired views, and the rig
    /// captures them as training pairs NTRAIN+1…NTRAIN+N (desired views in cam/desire/train);
    /// linear, linear-sl and the residual rungs then train on them by default.
    #[arg(long, value_name = "N", default_value_t = 0, value_parser = clap::value_parser!(u64).range(0..=500))]
    pub loop_images: u64,
    /// Print the setup's record (rig.json) on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(clap::Args, Debug)]
pub struct SheetArgs {
    /// Folder for the sheets: DIR/<scene>.png.
    #[arg(long)]
    pub out: PathBuf,
    /// Scenes (built-in names or JSON files); default: every built-in scene.
    #[arg(long)]
    pub scene: Vec<String>,
    #[command(flatten)]
    pub scene_args: SceneArgs,
    /// Which test image (sampling image of the test set, 1-based) to show.
    #[arg(long, default_value_t = 1)]
    pub image: usize,
    /// Panel width in pixels (panels are the camera frame scaled down), 16 to 4096.
    #[arg(long, default_value_t = 320, value_parser = clap::value_parser!(u16).range(16..=4096))]
    pub panel: u16,
}

pub fn parse_size(s: &str) -> std::result::Result<ImageSize, String> {
    parse_wxh(s, false)
}

pub fn parse_network(s: &str) -> std::result::Result<ImageSize, String> {
    let size = parse_wxh(s, true)?;
    if size.width % 4 != 0 || size.height % 4 != 0 {
        return Err(format!(
            "network size {size}: width and height must be divisible by 4"
        ));
    }
    Ok(size)
}

pub fn run(args: Args) -> Result<()> {
    match args.command {
        SimCommand::List => {
            for name in scene::BUILTIN {
                println!("{name}");
            }
            // Then the sets of projectors: `sim show` and `sim sheet --scene NAME` take them.
            for name in scene::SETS {
                println!("{name}");
            }
            Ok(())
        }
        SimCommand::Show { name } => {
            let s = scene::load(&name)?;
            println!("{}", serde_json::to_string_pretty(&s)?);
            Ok(())
        }
        SimCommand::Export(a) => export(a),
        SimCommand::Sheet(a) => sheet(a),
        SimCommand::Score(a) => score(a),
        SimCommand::SetScore(a) => set_score(a),
    }
}

/// Closed-loop pairs for an exported setup ([`rig::export::export_loop_pairs`]): `linear`
/// fitted on its sampling pairs compensates them. Returns how many were written.
pub fn loop_pairs(
    sim: &Simulator,
    setup: &compend::dataset::Setup,
    record: &rig::export::RigRecord,
    n: usize,
) -> Result<usize> {
    use compend::model::{Method, MethodChoice};
    let ntrain = record.train_captures;
    let req = compend::fit::Request {
        ntrain: Some(ntrain),
        seed: record.seed,
        ..compend::fit::Request::new(MethodChoice::Rung(Method::Linear))
    };
    let (model, _) = compend::fit::fit(setup, &req, |_, _, _| {})
        .context("fitting linear for the closed-loop pairs")?;
    rig::export::export_loop_pairs(sim, setup, record, &model, (ntrain, n))
        .context("taking the closed-loop pairs")?;
    Ok(n)
}

/// The exposure factor and display range `compend calibrate` recorded for the model in `dir`.
fn as_calibrated(dir: &std::path::Path) -> Result<(f64, compend::fov::DisplayRange)> {
    let model = compend::model::Model::load(dir)?;
    let calibration = model.meta.calibration.as_ref();
    let exposure = calibration.and_then(|c| c.exposure.as_ref());
    let range = calibration.and_then(|c| c.display_range);
    match (exposure, range) {
        (Some(e), Some(r)) => Ok((e.chosen, r)),
        _ => Err(compend::Error::Input(format!(
            "--as-calibrated {}: the model records no calibrated exposure and display range (it \
             was not made by `compend calibrate` on a camera with a manual exposure)",
            dir.display()
        ))
        .into()),
    }
}

/// The scene with the requested resolutions.
pub fn resolve(name: &str, a: &SceneArgs) -> Result<scene::Scene> {
    let s = scene::load(name)?;
    let cam = a.camera.unwrap_or(s.camera.size());
    let prj = a.projector.unwrap_or(s.projector.size());
    let s = s.with_resolution(cam, prj);
    s.validate()?;
    Ok(s)
}

fn export(a: ExportArgs) -> Result<()> {
    let mut scene = resolve(&a.scene, &a.scene_args)?;
    let mut desired_range = match a.desired_range {
        DesiredRange::Reachable => rig::DesiredScaling::Reachable,
        DesiredRange::Full => rig::DesiredScaling::Full,
    };
    if let Some(dir) = &a.as_calibrated {
        let (exposure, range) = as_calibrated(dir)?;
        scene.camera.exposure *= exposure;
        desired_range = rig::DesiredScaling::Given(range);
    }
    let sa = &a.scene_args;
    let setup = a
        .setup
        .clone()
        .unwrap_or_else(|| PathBuf::from(&scene.name));
    // Before anything is written.
    rig::export::check_setup_free(&a.out, &setup)?;
    rig::export::check_loop_slots(&a.out, &setup, a.ntrain as usize, a.loop_images as usize)?;
    // Projector-side images exactly as `compend patterns` writes them.
    super::patterns::run(super::patterns::Args {
        out: a.out.clone(),
        ntrain: a.ntrain,
        ntest: a.ntest,
        seed: sa.seed,
        size: sa.network,
        projector: scene.projector.size(),
        gray_level: patterns::DEFAULT_GRAY_LEVEL,
    })?;
    let phase = if a.drifted {
        Phase::AfterDrift
    } else {
        Phase::Calibration
    };
    eprintln!(
        "sim: preparing scene {:?} (camera {}, projector {}, seed {})",
        scene.name,
        scene.camera.size(),
        scene.projector.size(),
        sa.seed
    );
    let sim = Simulator::new(&scene, sa.seed, phase)?;
    let root = DataRoot::open(&a.out)?;
    let opts = ExportOptions {
        ntrain: a.ntrain as usize,
        ntest: a.ntest as usize,
        full_cube: !a.no_cube,
        structured_light: true,
        desired_range,
    };
    let summary = rig::export_setup(&sim, &root, &setup, &opts)
        .with_context(|| format!("exporting scene {:?} to {}", scene.name, a.out.display()))?;
    if a.loop_images > 0 {
        let setup = compend::dataset::Setup::open(&summary.setup, Some(root.path()))?;
        let t = std::time::Instant::now();
        let n = loop_pairs(&sim, &setup, &summary.record, a.loop_images as usize)?;
        eprintln!(
            "sim: {n} closed-loop pairs of linear's compensation in {:.1} s",
            t.elapsed().as_secs_f64()
        );
    }
    let r = &summary.record;
    eprintln!(
        "sim: wrote {} ({} ref, {} sl, {} train, {} test captures; displayable area {}; FOV \
         {:.1}% of the frame, truly lit {:.1}%) in {:.1} s",
        summary.setup.display(),
        r.ref_captures,
        r.sl_captures,
        r.train_captures,
        r.test_captures,
        r.displayable_area,
        100.0 * r.fov_coverage,
        100.0 * r.true_fov_coverage,
        summary.seconds
    );
    if a.json {
        println!("{}", serde_json::to_string(r)?);
    }
    Ok(())
}

fn sheet(a: SheetArgs) -> Result<()> {
    let names: Vec<String> = if a.scene.is_empty() {
        scene::BUILTIN.iter().map(|s| s.to_string()).collect()
    } else {
        a.scene.clone()
    };
    if a.image == 0 {
        return Err(compend::Error::Input("--image counts from 1".into()).into());
    }
    super::check_out_folder(&a.out, "--out")?;
    let sa = &a.scene_args;
    // Every scene resolved first: a bad one is refused before anything is written, and only
    // sheets an earlier `sim sheet` wrote are replaced.
    let scenes: Vec<scene::Scene> = names
        .iter()
        .map(|n| resolve(n, sa))
        .collect::<Result<_>>()?;
    let files: Vec<String> = scenes.iter().map(|s| format!("{}.png", s.name)).collect();
    if let Some(twice) = files
        .iter()
        .enumerate()
        .find(|(i, f)| files[..*i].contains(f))
    {
        return Err(compend::Error::Input(format!(
            "two scenes are named {:?}; their sheets would have one file",
            twice.1.trim_end_matches(".png")
        ))
        .into());
    }
    let mut owned = super::OwnedOut::open(&a.out, "--out", ".compend-sheets", "compend sim sheet")?;
    owned.check(&files)?;
    owned.claim(&files)?;
    let (nw, nh) = (sa.network.width, sa.network.height);
    let sample = patterns::sampling_image(sa.seed, Set::Train, a.image - 1, nw, nh);
    let test = patterns::sampling_image(sa.seed, Set::Test, a.image - 1, nw, nh);
    // The reference rows' header, over the single-projector scenes' rows; a set's row says its
    // own figures.
    if scenes.iter().any(|s| s.more_projectors.is_empty()) {
        println!(
            "{:<16} {:>22} {:>22} {:>22}",
            "scene", "uncompensated", "geometry-only", "oracle"
        );
    }
    for scene in &scenes {
        let name = &scene.name;
        if !scene.more_projectors.is_empty() {
            let set = rig::SetSimulator::new(scene, sa.seed, Phase::Calibration)?;
            let (img, s) = rig::sheet::set_sheet(&set, &test, usize::from(a.panel))
                .with_context(|| format!("the sheet of the set {name:?}"))?;
            let path = a.out.join(format!("{}.png", scene.name));
            compend::pngio::write_rgb(&path, &img)?;
            let cell = |x: &compend::metrics::Scores| format!("{:.2} dB / {:.3}", x.psnr, x.ssim);
            println!(
                "{:<16} projector 1 alone {} (white {:.3}); joint {} (white {:.3}; seam {})",
                scene.name,
                cell(&s.first_alone),
                s.first_range.high,
                cell(&s.joint),
                s.range.high,
                s.seam
                    .map_or("none crosses the area".to_string(), |f| format!(
                        "{:.2}",
                        f.ratio()
                    ))
            );
            eprintln!("sim: wrote {}", path.display());
            continue;
        }
        let sim = Simulator::new(scene, sa.seed, Phase::Calibration)?;
        let (area, range) = rig::sheet::display_target(&sim)
            .with_context(|| format!("finding the displayable area of scene {name:?}"))?;
        let (img, s) =
            rig::sheet::contact_sheet(&sim, &sample, &test, area, range, usize::from(a.panel))?;
        let path = a.out.join(format!("{}.png", scene.name));
        compend::pngio::write_rgb(&path, &img)?;
        let cell = |x: &compend::metrics::Scores| format!("{:.2} dB / {:.3}", x.psnr, x.ssim);
        println!(
            "{:<16} {:>22} {:>22} {:>22}",
            scene.name,
            cell(&s.uncompensated),
            cell(&s.geometry_only),
            cell(&s.oracle)
        );
        eprintln!("sim: wrote {}", path.display());
    }
    Ok(())
}

/// One row of `sim score`.
#[derive(serde::Serialize)]
struct Row {
    name: String,
    psnr: f64,
    rmse: f64,
    ssim: f64,
    /// PSNR below the oracle's, dB.
    gap_db: f64,
}

impl Row {
    /// A row of scores `s`, its gap measured to the oracle's PSNR `ceiling` (dB).
    fn new(name: &str, s: &compend::metrics::Scores, ceiling: f64) -> Self {
        Self {
            name: name.to_string(),
            psnr: s.psnr,
            rmse: s.rmse,
            ssim: s.ssim,
            gap_db: ceiling - s.psnr,
        }
    }
}

/// First frame index of the closed-loop captures (apart from the export's).
const FRAMES_SCORE: u64 = 2_000_000;

/// The list `sim score --out` keeps in its folder of the camera views it wrote there.
const SCORE_MARKER: &str = ".compend-scored";

fn score(a: ScoreArgs) -> Result<()> {
    use compend::dataset::ProjectorSet;

    let setup = a.setup.open()?;
    let record = rig::export::read_record(setup.path())?;
    let phase = if a.no_drift {
        Phase::Calibration
    } else {
        Phase::AfterDrift
    };
    let sim = Simulator::new(&record.scene, record.seed, phase)?;
    let n_desired = setup.count_desired()?;
    let n = a.ntest.map_or(n_desired, |k| k.min(n_desired));
    let frames = rig::score::Frames {
        first: FRAMES_SCORE,
        average: a.average as usize,
    };
    if n == 0 {
        return Err(compend::Error::Input(format!(
            "{}: no desired images in cam/desire/test to score against",
            setup.path().display()
        ))
        .into());
    }
    let models = if a.model.is_empty() {
        setup.compensated_models()?
    } else {
        a.model.clone()
    };
    // Where the camera views go, checked before any work: outside the data root (views in it
    // would be taken for models or captures), and replacing only views an earlier run wrote.
    let mut out = match &a.out {
        Some(dir) => {
            let owned = super::OwnedOut::open(dir, "--out", SCORE_MARKER, "compend sim score")?;
            let root = setup.root().path().canonicalize().ok();
            let inside = root
                .as_ref()
                .is_some_and(|r| super::resolved(dir).is_ok_and(|d| d.starts_with(r)));
            if inside {
                return Err(compend::Error::Input(format!(
                    "--out {}: inside the data root {}; the camera views would be taken for \
                     models or captures: choose a folder outside it",
                    dir.display(),
                    setup.root().path().display()
                ))
                .into());
            }
            // Each model's views go into a folder of its name: a plain name, and none of the
            // reference rows'.
            for m in &models {
                setup.compensation_dir(m)?;
                if ["desired", "uncompensated", "oracle"].contains(&m.as_str()) {
                    return Err(compend::Error::Input(format!(
                        "--model {m}: with --out, a model may not be named like a reference row \
                         (desired, uncompensated, oracle), whose views have that folder"
                    ))
                    .into());
                }
            }
            let names: Vec<String> = models
                .iter()
                .map(String::as_str)
                .chain(["desired", "uncompensated", "oracle"])
                .flat_map(|folder| {
                    (1..=n).map(move |k| format!("{folder}/{}", compend::pngio::indexed_name(k)))
                })
                .collect();
            Some((owned, names))
        }
        None => None,
    };
    if let Some((owned, names)) = &mut out {
        owned.check(names)?;
        owned.claim(names)?;
    }
    let desired = setup.load_desired(Some(n))?;
    let area = record.displayable_area;
    let psize = sim.projector_size();
    let tests = on_canvas(
        setup.root().load(ProjectorSet::Test, Some(n))?,
        record.canvas,
        psize,
    )?;
    let pose = match (&record.scene.drift, phase) {
        (Some(_), Phase::AfterDrift) => ", projector moved after calibration",
        (Some(_), Phase::Calibration) => ", projector where it was at calibration",
        (None, _) => "",
    };
    eprintln!(
        "sim: scoring {n} test image(s) of scene {:?} on the rig (area {area}{pose})",
        record.scene.name
    );
    let net = setup.root().network_size()?;
    let r = rig::score::references(
        &sim,
        &tests,
        &desired,
        area,
        (record.canvas, net),
        rig::OracleOptions {
            iterations: a.oracle_iterations,
        },
        frames,
    )?;
    let (refs, oracle_images, net_oracle) = (r.scores, r.oracle_images, r.oracle_at_network);
    let ceiling = refs.oracle.psnr;
    let mut rows = vec![
        Row::new("uncompensated", &refs.uncompensated, ceiling),
        Row::new("geometry-only", &refs.geometry_only, ceiling),
    ];
    for m in &models {
        let shown = on_canvas(read_compensation(&setup, m, n)?, record.canvas, psize)?;
        let s = rig::closed_loop(&sim, &shown, &desired, area, frames)
            .with_context(|| format!("scoring model {m:?}"))?;
        rows.push(Row::new(m, &s, ceiling));
        if let Some(out) = &a.out {
            write_views(&sim, &shown, area, frames, &out.join(m))?;
        }
    }
    if let Some(out) = &a.out {
        let crops: Vec<_> = desired
            .iter()
            .map(|z| z.crop(area))
            .collect::<compend::Result<_>>()?;
        write_images(&crops, &out.join("desired"))?;
        write_views(&sim, &tests, area, frames, &out.join("uncompensated"))?;
        write_views(&sim, &oracle_images, area, frames, &out.join("oracle"))?;
        eprintln!("sim: wrote the camera views to {}", out.display());
    }
    rows.push(Row::new(&format!("oracle @ {net}"), &net_oracle, ceiling));
    rows.push(Row::new("oracle", &refs.oracle, ceiling));
    print_scores(a.json, &record, phase, (n, frames.average), &rows);
    Ok(())
}

/// Projector images (network size, or a model's own lattice) stretched over the canvas
/// (projector pixels) of a projector of `psize` (width, height) pixels.
fn on_canvas(
    imgs: Vec<compend::raster::PrjImage>,
    canvas: compend::raster::Rect,
    psize: ImageSize,
) -> compend::Result<Vec<compend::raster::PrjImage>> {
    imgs.iter()
        .map(|i| compend::playback::place_on_canvas(i, canvas, psize))
        .collect()
}

/// The first `n` compensation images of model `m` (`prj/cmp/test/<m>`), all of one size.
fn read_compensation(
    setup: &compend::dataset::Setup,
    m: &str,
    n: usize,
) -> Result<Vec<compend::raster::PrjImage>> {
    let dir = setup.compensation_dir(m)?;
    // Any size is stretched over the canvas (a `linear` model's lattice can be finer than the
    // network), but one model's images must all have one size.
    let imgs: Vec<compend::raster::PrjImage> = (1..=n)
        .map(|i| compend::pngio::read_rgb(&dir.join(compend::pngio::indexed_name(i))))
        .collect::<compend::Result<_>>()?;
    if let Some((i, img)) = imgs
        .iter()
        .enumerate()
        .find(|(_, m)| m.size() != imgs[0].size())
    {
        return Err(compend::Error::Input(format!(
            "{}: {}x{}, expected {}x{} like {}",
            dir.join(compend::pngio::indexed_name(i + 1)).display(),
            img.width(),
            img.height(),
            imgs[0].width(),
            imgs[0].height(),
            compend::pngio::indexed_name(1)
        ))
        .into());
    }
    Ok(imgs)
}

/// Prints the rows: one JSON object with `json`, else a table (PSNR dB, RMSE and SSIM of the
/// displayable area, gap to the oracle in dB) of `n` test images, each captured as the mean of
/// `average` frames.
fn print_scores(
    json: bool,
    record: &rig::export::RigRecord,
    phase: Phase,
    (n, average): (usize, usize),
    rows: &[Row],
) {
    let area = record.displayable_area;
    if json {
        let out = serde_json::json!({
            "scene": record.scene.name,
            "seed": record.seed,
            "phase": phase,
            "n": n,
            "frames_averaged": average,
            "displayable_area": area,
            "rows": rows,
        });
        println!("{out}");
    } else {
        println!(
            "{:<24} {:>9} {:>9} {:>9} {:>12}",
            "row", "PSNR", "RMSE", "SSIM", "gap (dB)"
        );
        for r in rows {
            println!(
                "{:<24} {:>9.4} {:>9.4} {:>9.4} {:>12.2}",
                r.name, r.psnr, r.rmse, r.ssim, r.gap_db
            );
        }
        let frames = match average {
            1 => String::new(),
            k => format!(", each the mean of {k} frames"),
        };
        println!(
            "({n} test image(s){frames}, closed loop in the {}x{} displayable area)",
            area.width, area.height
        );
    }
}

/// Captures each projector image as `score` does and writes the displayable area of each.
fn write_views(
    sim: &Simulator,
    shown: &[compend::raster::PrjImage],
    area: compend::raster::Rect,
    frames: rig::score::Frames,
    dir: &std::path::Path,
) -> Result<()> {
    let views: Vec<_> = shown
        .iter()
        .enumerate()
        .map(|(k, p)| frames.capture(sim, p, k)?.crop(area))
        .collect::<compend::Result<_>>()?;
    write_images(&views, dir)
}

fn write_images<S: compend::raster::Space>(
    imgs: &[compend::raster::Rgb<S>],
    dir: &std::path::Path,
) -> Result<()> {
    for (k, img) in imgs.iter().enumerate() {
        let p = dir.join(compend::pngio::indexed_name(k + 1));
        compend::pngio::write_rgb(&p, img).with_context(|| format!("writing {}", p.display()))?;
    }
    Ok(())
}

/// How desired images are scaled (see `--desired-range`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum DesiredRange {
    Reachable,
    Full,
}

/// `compend sim set-score`: rebuilds the set's virtual rig from the model's record (scene,
/// seed, sizes) and scores the joint model on the views its calibration verified.
fn set_score(a: SetScoreArgs) -> Result<()> {
    use compend::model::set::SetModel;

    let model = SetModel::load(&a.model)?;
    let record = model.meta.calibration.as_ref().ok_or_else(|| {
        compend::Error::Input(format!(
            "{}: no calibration record in set.json: only a set calibrated on the virtual rig \
             can be scored against its ceiling",
            a.model.display()
        ))
    })?;
    let Some(name) = record.rig.strip_prefix("virtual:") else {
        return Err(compend::Error::Input(format!(
            "{}: calibrated on {:?}, not on the virtual rig (`virtual:SCENE`)",
            a.model.display(),
            record.rig
        ))
        .into());
    };
    let first = &model.models[0];
    let seed = first
        .meta
        .calibration
        .as_ref()
        .and_then(|c| c.seed)
        .ok_or_else(|| {
            compend::Error::Input(format!(
                "{}: projector 1's record has no seed",
                a.model.display()
            ))
        })?;
    let projector = first
        .meta
        .canvas
        .map(|c| ImageSize::new(c.width, c.height))
        .unwrap_or(first.network_size());
    let mut scene = scene::load(name)?.with_resolution(model.meta.camera_size, projector);
    // The calibration ranged the camera's exposure (a factor of the scene's): the models see
    // through it, and so does the score.
    if let Some(e) = &record.exposure {
        scene.camera.exposure *= e.chosen;
    }
    let set = rig::SetSimulator::new(&scene, seed, Phase::Calibration)?;
    let dir = a.data.join(compend::calibrate::set::SET_DIR);
    let mut desired = Vec::new();
    for i in 1.. {
        let path = dir.join(format!("desired-{i:03}.png"));
        if !path.is_file() || a.ntest.is_some_and(|n| desired.len() >= n) {
            break;
        }
        desired.push(compend::pngio::read_rgb_sized(
            &path,
            model.meta.camera_size,
            "a desired view of the set's verification",
        )?);
    }
    if desired.is_empty() {
        return Err(compend::Error::Missing {
            path: dir.join("desired-001.png"),
            expected: "the desired views the set's calibration verified on".into(),
        }
        .into());
    }
    let joint = model.joint()?;
    eprintln!(
        "sim: scoring the joint model of {} projectors on {} view(s) of scene {name:?}, seed \
         {seed}, area {}",
        model.models.len(),
        desired.len(),
        record.area
    );
    let s = rig::set_score::score_set(
        &set,
        (&joint, &model.models),
        &desired,
        record.area,
        rig::OracleOptions {
            iterations: a.oracle_iterations,
        },
    )?;
    if a.json {
        println!("{}", serde_json::to_string(&s)?);
        return Ok(());
    }
    let gap = s.ceiling.psnr - s.joint.psnr;
    println!(
        "joint     {:.2} dB  SSIM {:.3}  ({gap:.2} dB below the ceiling)",
        s.joint.psnr, s.joint.ssim
    );
    println!(
        "ceiling   {:.2} dB  SSIM {:.3}",
        s.ceiling.psnr, s.ceiling.ssim
    );
    for (k, al) in s.alone.iter().enumerate() {
        println!(
            "alone {}   {:.2} dB  SSIM {:.3}  (unreachable {:.1} % of the area in the set's \
             range, {:.1} % in its own)",
            k + 1,
            al.psnr,
            al.ssim,
            s.alone_unreachable_at_set_range_percent[k],
            s.alone_unreachable_percent[k]
        );
    }
    println!("set unreachable {:.1} % of the area", s.unreachable_percent);
    let seam = |f: &Option<compend::metrics::SeamFigure>| {
        f.map_or("no overlap edge in the area".to_string(), |f| {
            format!("{:.2}", f.ratio())
        })
    };
    println!(
        "seam      joint {}  ceiling {}",
        seam(&s.joint_seam),
        seam(&s.ceiling_seam)
    );
    Ok(())
}
