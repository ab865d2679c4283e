//! `compend bench`: methods × scenes × training-set sizes × seeds on the virtual rig
//! (docs/architecture.md, "Data flow": monitor). For every scene and seed it exports a setup,
//! scores the reference rows (uncompensated, geometry-only, the oracle at network resolution and
//! the oracle), then trains every method at every training-set size and scores it with the paper
//! protocol and closed loop on the rig. Writes `bench.json` (every row), `bench.md` (tables) and
//! two PNG charts (accuracy against training time and against per-frame time); progress on
//! stderr.

mod chart;
mod row;

pub use row::Row;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use compend::dataset::{DataRoot, ProjectorSet, Setup};
use compend::fit::{self, Request};
use compend::model::paper_protocol;
use compend::raster::{CamImage, PrjImage};
use compend::record::ClosedLoopScore;
use compend::rig::{self, ExportOptions, OracleOptions, Phase, Simulator};

use crate::cli::sim::SceneArgs;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Folder for bench.json, bench.md, the charts (accuracy-vs-training.png,
    /// accuracy-vs-frame.png) and the simulated data (data/).
    #[arg(long)]
    pub out: PathBuf,
    /// Scenes, comma-separated [default: every built-in scene].
    #[arg(long, value_delimiter = ',')]
    pub scenes: Vec<String>,
    /// Methods, comma-separated.
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "linear,linear-sl"
    )]
    pub methods: Vec<compend::model::MethodChoice>,
    /// Training-set sizes, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "48")]
    pub ntrain: Vec<usize>,
    /// Seeds (scene texture, noise and sampling images), comma-separated; several seeds test
    /// stability.
    #[arg(long, value_delimiter = ',', default_value = "0")]
    pub seeds: Vec<u64>,
    /// Test images per scene.
    #[arg(long, default_value_t = 10)]
    pub ntest: usize,
    #[command(flatten)]
    pub network: crate::cli::NetworkFlags,
    /// `auto`: the PSNR gain in dB the CompenNet++ rung, trained on every pair, needs over the
    /// best linear rung in closed loop on the rig as calibrated (5 verification images after
    /// the scored ones), as `calibrate` judges it [default: 0.2].
    #[arg(long, value_name = "DB", allow_hyphen_values = true)]
    pub climb_gain: Option<f64>,
    /// Closed-loop pairs, as `compend calibrate` takes them (one --ntrain size only): after the
    /// export, `linear` fitted on the sampling pairs compensates N sampling images placed as
    /// desired views and the rig captures them; linear, linear-sl and the residual rungs then
    /// train on every pair (the correction on the closed-loop ones), auto judges its climb on
    /// them (8 or more), the other methods train on the sampling pairs alone [default: 0,
    /// none].
    #[arg(long, value_name = "N", default_value_t = 0, value_parser = clap::value_parser!(u64).range(0..=500))]
    pub loop_images: u64,
    /// `auto` only: weigh its climb's live pass for a display refreshing at HZ, on this
    /// machine's GPU, as `train --refresh-hz` does: the rung it would climb to is not trained
    /// when its pass takes more than half of one refresh period at the scene's projector
    /// resolution. Default, or 0: not weighed.
    #[arg(long, value_name = "HZ", allow_hyphen_values = true)]
    pub refresh_hz: Option<f64>,
    /// Camera / projector / network sizes (defaults: the scenes' 640x480 / 800x600, 256).
    #[command(flatten)]
    pub scene_args: SceneArgs,
}

/// Frame indices of the closed-loop captures (apart from the export's).
const FRAMES_BENCH: u64 = 3_000_000;

pub fn run(args: Args) -> Result<()> {
    let start = Instant::now();
    let scenes: Vec<String> = if args.scenes.is_empty() {
        rig::BUILTIN.iter().map(|s| s.to_string()).collect()
    } else {
        args.scenes.clone()
    };
    let max_train = *args
        .ntrain
        .iter()
        .max()
        .context("--ntrain needs at least one size")?;
    // As `sim export` takes them: the sets are written to disk for every scene and seed.
    let most = 9999;
    let fewest = args.ntrain.iter().min().copied().unwrap_or(0);
    if fewest < fit::MIN_TRAIN
        || max_train > most
        || args.ntest == 0
        || args.ntest > most
        || args.seeds.is_empty()
    {
        return Err(compend::Error::Input(format!(
            "--ntrain sizes must be from {} to {most}, --ntest from 1 to {most}, and --seeds \
             non-empty",
            fit::MIN_TRAIN
        ))
        .into());
    }
    // A value given twice would run the same work twice.
    let twice = |flag: &str, values: Vec<String>| -> compend::Result<()> {
        let mut seen = std::collections::BTreeSet::new();
        match values.into_iter().find(|v| !seen.insert(v.clone())) {
            Some(v) => Err(compend::Error::Input(format!("{flag}: {v} is given twice"))),
            None => Ok(()),
        }
    };
    // By the name each scene has (a scene file may hold a built-in's name): its data root and
    // rows are named by it.
    let names = scenes
        .iter()
        .map(|s| rig::scene::load(s).map(|scene| scene.name))
        .collect::<compend::Result<Vec<_>>>()?;
    twice("--scenes (by scene name)", names)?;
    twice(
        "--ntrain",
        args.ntrain.iter().map(|n| n.to_string()).collect(),
    )?;
    twice(
        "--seeds",
        args.seeds.iter().map(|n| n.to_string()).collect(),
    )?;
    twice(
        "--methods",
        args.methods.iter().map(|m| m.to_string()).collect(),
    )?;
    if args.loop_images > 0 && args.ntrain.len() > 1 {
        return Err(compend::Error::Input(format!(
            "--loop-images {}: closed-loop pairs follow the sampling pairs, so give one --ntrain \
             size, not {}",
            args.loop_images,
            args.ntrain.len()
        ))
        .into());
    }
    compend::files::check_out_folder(&args.out)?;
    // A device this build or machine cannot train on fails before any scene is exported, when
    // a method trains on it.
    let trains = args.methods.iter().any(|m| m.may_train_a_network());
    if trains && args.network.device != fit::TrainDevice::Cpu {
        args.network.device.candle()?;
    }
    if let Some(g) = args.climb_gain {
        if !g.is_finite() {
            return Err(compend::Error::Input(format!(
                "--climb-gain {g}: expected a number of dB"
            ))
            .into());
        }
        if !args.methods.contains(&compend::model::MethodChoice::Auto) {
            return Err(compend::Error::Input(format!(
                "--climb-gain {g}: only the `auto` method climbs the ladder; add auto to --methods"
            ))
            .into());
        }
        if let Some(w) = (fit::ClimbRule { gain_db: g }).caveat("--climb-gain") {
            eprintln!("warning: {w}");
        }
    }
    let live = super::refresh_timer(
        args.refresh_hz,
        args.methods.contains(&compend::model::MethodChoice::Auto),
        "add auto to --methods",
    )?;
    let mut rows = Vec::new();
    let mut reach = Vec::new();
    for &seed in &args.seeds {
        let sa = SceneArgs {
            seed,
            camera: args.scene_args.camera,
            projector: args.scene_args.projector,
            network: args.scene_args.network,
        };
        for name in &scenes {
            let scene = super::sim::resolve(name, &sa)?;
            eprintln!("bench: scene {} seed {seed}", scene.name);
            // Each scene has a data root of its own: its closed-loop pairs are its own
            // compensation images, and its projector may have a resolution of its own (a
            // root's images are never replaced by others).
            let root_dir = args
                .out
                .join("data")
                .join(format!("seed{seed}-{}", scene.name));
            rig::export::check_loop_slots(
                &root_dir,
                Path::new(&scene.name),
                max_train,
                args.loop_images as usize,
            )?;
            super::patterns::run(super::patterns::Args {
                out: root_dir.clone(),
                ntrain: max_train as u64,
                ntest: args.ntest as u64,
                seed,
                size: sa.network,
                projector: scene.projector.size(),
                gray_level: compend::patterns::DEFAULT_GRAY_LEVEL,
            })
            .with_context(|| {
                format!(
                    "the bench's data root {} (another --network or --ntrain than the run \
                     that wrote it?): choose another --out",
                    root_dir.display()
                )
            })?;
            let root = DataRoot::open(&root_dir)?;
            let sim = Simulator::new(&scene, seed, Phase::Calibration)?;
            let opts = ExportOptions {
                ntrain: max_train,
                ntest: args.ntest,
                full_cube: false,
                structured_light: true,
                desired_range: rig::DesiredScaling::Reachable,
            };
            let exported =
                rig::export::export_setup(&sim, &root, &PathBuf::from(&scene.name), &opts)
                    .with_context(|| format!("exporting scene {}", scene.name))?;
            let setup = Setup::open(&exported.setup, Some(root.path()))?;
            if args.loop_images > 0 {
                super::sim::loop_pairs(&sim, &setup, &exported.record, args.loop_images as usize)
                    .with_context(|| format!("scene {}", scene.name))?;
            }
            // Score as the viewer will see it: after the projector moved, for the drift scene.
            let viewer = Simulator::new(&scene, seed, Phase::AfterDrift)?;
            rows.extend(bench_scene(
                &args,
                live.as_ref(),
                &scene.name,
                seed,
                (&sim, &viewer),
                &setup,
                &exported.record,
            )?);
            reach.push(scene_reach(&scene.name, seed, &setup, &exported.record)?);
        }
    }
    std::fs::create_dir_all(&args.out)
        .map_err(|e| compend::Error::io(&args.out, "create folder", e))?;
    let json = serde_json::json!({
        "compend": env!("CARGO_PKG_VERSION"),
        "threads": std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1),
        // Where the CompenNet++ rungs (and `auto`'s climb) trained.
        "device": args.network.device.to_string(),
        "seconds": start.elapsed().as_secs_f64(),
        "ntest": args.ntest,
        "rows": rows,
        "unreachable": reach,
    });
    let jpath = args.out.join("bench.json");
    compend::files::write_atomically(&jpath, &serde_json::to_vec_pretty(&json)?)?;
    let mpath = args.out.join("bench.md");
    compend::files::write_atomically(
        &mpath,
        markdown(&rows, &reach, args.network.device).as_bytes(),
    )?;
    let charts = chart::write_charts(&rows, &args.out)?;
    eprintln!(
        "bench: {} rows in {:.0} s; wrote {}, {} and {} chart(s)",
        rows.len(),
        start.elapsed().as_secs_f64(),
        jpath.display(),
        mpath.display(),
        charts.len()
    );
    Ok(())
}

/// Where no model can compensate in one scene and seed: the share of the displayable area by
/// reason (from the calibration's black and white captures against the desired range), and
/// the picture written as the setup's `cam/unreachable.png`.
#[derive(serde::Serialize)]
struct SceneReach {
    scene: String,
    seed: u64,
    #[serde(flatten)]
    summary: compend::fov::ReachSummary,
}

fn scene_reach(
    scene: &str,
    seed: u64,
    setup: &Setup,
    record: &rig::export::RigRecord,
) -> Result<SceneReach> {
    use compend::dataset::Reference;
    let black = setup.load_reference(Reference::Black)?;
    let white = setup.load_reference(Reference::White)?;
    let reach = compend::fov::reach(
        &black,
        &white,
        record.displayable_area,
        record.desired_range,
    )?;
    compend::pngio::write_rgb(&setup.unreachable_path(), &reach.picture(&white)?)?;
    Ok(SceneReach {
        scene: scene.into(),
        seed,
        summary: reach.summary(),
    })
}

fn bench_scene(
    args: &Args,
    live: Option<&std::sync::Arc<dyn fit::LivePass>>,
    scene: &str,
    seed: u64,
    (calibration, sim): (&Simulator, &Simulator),
    setup: &Setup,
    record: &rig::export::RigRecord,
) -> Result<Vec<Row>> {
    let bench = SceneBench {
        args,
        live,
        scene,
        seed,
        calibration,
        sim,
        setup,
        record,
        desired: setup.load_desired(Some(args.ntest))?,
    };
    let (mut rows, ceiling) = bench.reference_rows()?;
    let uncompensated = rows[0].closed_loop.map_or(f64::NAN, |s| s.psnr);
    let test_pairs = setup.load_test(Some(args.ntest))?;
    for &method in &args.methods {
        for &n in &args.ntrain {
            let refs = (ceiling, uncompensated);
            rows.push(bench.method_row(method, n, &test_pairs, refs)?);
        }
    }
    Ok(rows)
}

/// One scene and seed of the bench: the rig as it was calibrated and as the viewer sees it, the
/// exported setup and its record, and the desired test images (camera pixels).
struct SceneBench<'a> {
    args: &'a Args,
    /// `auto`'s timer of its climb's live pass (`--refresh-hz`).
    live: Option<&'a std::sync::Arc<dyn fit::LivePass>>,
    scene: &'a str,
    seed: u64,
    /// The rig during calibration: where `auto`'s climb is checked in closed loop.
    calibration: &'a Simulator,
    sim: &'a Simulator,
    setup: &'a Setup,
    record: &'a rig::export::RigRecord,
    desired: Vec<compend::raster::CamImage>,
}

impl SceneBench<'_> {
    /// Projector images stretched over the record's canvas (projector pixels).
    fn on_canvas(&self, imgs: &[PrjImage]) -> compend::Result<Vec<PrjImage>> {
        let psize = self.sim.projector_size();
        imgs.iter()
            .map(|i| compend::playback::place_on_canvas(i, self.record.canvas, psize))
            .collect()
    }

    /// The reference rows (uncompensated, geometry-only, the oracle at network resolution and
    /// the oracle) and the oracle's PSNR (dB), the ceiling every gap is measured to.
    fn reference_rows(&self) -> Result<(Vec<Row>, f64)> {
        let (args, scene, seed, sim) = (self.args, self.scene, self.seed, self.sim);
        let area = self.record.displayable_area;
        let tests = self.on_canvas(
            &self
                .setup
                .root()
                .load(ProjectorSet::Test, Some(args.ntest))?,
        )?;
        let net = self.setup.root().network_size()?;
        let r = rig::score::references(
            sim,
            &tests,
            &self.desired,
            area,
            (self.record.canvas, net),
            OracleOptions::default(),
            rig::score::Frames::single(FRAMES_BENCH),
        )?;
        let (refs, net_oracle) = (r.scores, r.oracle_at_network);
        let ceiling = refs.oracle.psnr;
        let rows = vec![
            Row::reference(scene, seed, "uncompensated", refs.uncompensated, ceiling),
            Row::reference(scene, seed, "geometry-only", refs.geometry_only, ceiling),
            Row::reference(scene, seed, "oracle@network", net_oracle, ceiling),
            Row::reference(scene, seed, "oracle", refs.oracle, ceiling),
        ];
        Ok((rows, ceiling))
    }

    /// Trains `method` on the first `n` pairs and scores it: the paper protocol on the test
    /// pairs, the CPU time per frame (ms), closed loop on the rig with its gap to `ceiling`
    /// (dB), and how it failed ([`compend::failure`], against the `uncompensated` closed-loop
    /// PSNR). A failed training is a row that says so.
    fn method_row(
        &self,
        method: compend::model::MethodChoice,
        n: usize,
        test_pairs: &compend::dataset::Pairs,
        (ceiling, uncompensated): (f64, f64),
    ) -> Result<Row> {
        let (args, scene, seed) = (self.args, self.scene, self.seed);
        let trains = !matches!(method, compend::model::MethodChoice::Rung(m) if m.is_linear());
        // As `calibrate`: the methods that take closed-loop pairs train on them too (`auto`
        // compares the linear rungs on the sampling pairs and trains the residual rung on every
        // pair for the rig to judge).
        let loops = (compend::calibrate::refines(method) && args.loop_images > 0)
            .then_some(args.loop_images as usize);
        let req = Request {
            ntrain: Some(n + loops.unwrap_or(0)),
            seed,
            // The closed-form linear rungs train in no iterations.
            iters: args.network.iters.filter(|_| trains),
            batch: args.network.batch.filter(|_| trains),
            device: args.network.device,
            climb_gain_db: args
                .climb_gain
                .filter(|_| method == compend::model::MethodChoice::Auto),
            live: self
                .live
                .filter(|_| method == compend::model::MethodChoice::Auto)
                .cloned(),
            // `auto`'s climb is checked on the rig as calibrated ([`SceneBench::confirm_on_rig`]).
            rig_judges: method == compend::model::MethodChoice::Auto,
            ..Request::new(method)
        };
        let mut row = Row {
            scene: scene.into(),
            seed,
            method: method.to_string(),
            ntrain: Some(n),
            train_seconds: None,
            loop_pairs: loops,
            captures: Some(
                n + 3
                    + loops.unwrap_or(0)
                    + if method.name().ends_with("-sl") {
                        self.record.sl_captures
                    } else {
                        0
                    },
            ),
            frame_ms_cpu: None,
            paper: None,
            closed_loop: None,
            gap_db: None,
            failed: None,
            failure: None,
            chosen: None,
            rig_check: Vec::new(),
            loop_held_out: None,
            live: None,
        };
        let trained = fit::fit(self.setup, &req, |_, _, _| {}).and_then(|(model, summary)| {
            if method != compend::model::MethodChoice::Auto {
                return Ok((model, summary));
            }
            let t = Instant::now();
            let model = self.confirm_on_rig(model, &req)?;
            let seconds = summary.seconds + t.elapsed().as_secs_f64();
            Ok((model, fit::Summary { seconds, ..summary }))
        });
        match trained {
            Err(e) => {
                eprintln!("bench: {scene} {method} n={n}: training failed: {e}");
                row.failed = Some(e.to_string());
            }
            Ok((model, summary)) => {
                row.train_seconds = Some(summary.seconds);
                row.paper = Some(paper_protocol(&model, test_pairs)?.0);
                let desired = &self.desired;
                let t = Instant::now();
                let shown: Vec<PrjImage> = desired
                    .iter()
                    .map(|z| model.infer(z).map(|x| x.into_space()))
                    .collect::<compend::Result<_>>()?;
                row.frame_ms_cpu = Some(1e3 * t.elapsed().as_secs_f64() / desired.len() as f64);
                let area = self.record.displayable_area;
                let s = rig::closed_loop(
                    self.sim,
                    &self.on_canvas(&shown)?,
                    desired,
                    area,
                    rig::score::Frames::single(FRAMES_BENCH),
                )?;
                row.gap_db = Some(ceiling - s.psnr);
                row.closed_loop = Some(s);
                let inputs: Vec<&CamImage> = desired.iter().collect();
                let outputs: Vec<&PrjImage> = shown.iter().collect();
                row.failure = compend::failure::classify(&inputs, &outputs, s.psnr, uncompensated);
                if let Some(a) = &model.meta.training.auto {
                    row.chosen = Some(a.chosen.to_string());
                    row.rig_check = a.closed_loop.clone();
                    row.loop_held_out = a.loop_held_out.clone();
                    row.live = a.live.clone();
                }
                eprintln!(
                    "bench: {scene} {method}{} n={n}: {:.1} s, closed loop {:.2} dB (gap {:.2} \
                     dB){}{}{}",
                    row.chosen
                        .as_ref()
                        .map_or(String::new(), |c| format!(" → {c}")),
                    summary.seconds,
                    s.psnr,
                    ceiling - s.psnr,
                    row.failure.map_or(String::new(), |f| format!(", {f}")),
                    row.live
                        .as_ref()
                        .map_or(String::new(), |l| format!("; {}", l.describe())),
                    row.loop_held_out.as_ref().map_or(String::new(), |l| {
                        let psnr: Vec<String> = l
                            .scores
                            .iter()
                            .map(|c| format!("{} {:.2}", c.method, c.held_out_psnr))
                            .collect();
                        format!(
                            "; on {} held-out closed-loop pairs: {} dB{}",
                            l.pairs,
                            psnr.join(", "),
                            l.training.stop()
                        )
                    })
                );
            }
        }
        Ok(row)
    }
}

impl SceneBench<'_> {
    /// `auto` as `calibrate` runs it: after a climb, the best linear rung fitted beside the
    /// climbed one, both projected on [`CONFIRM_IMAGES`] verification images on the rig as it
    /// was calibrated, and the rig's verdict ([`fit::settle_climb`]). The verification images
    /// are sampling images of the test set after the scored ones, so the choice is made on
    /// images the bench does not score.
    fn confirm_on_rig(
        &self,
        climbed: compend::model::Model,
        req: &Request,
    ) -> compend::Result<compend::model::Model> {
        let Some(lower) = fit::lower_rung(self.setup, req, &climbed, |_, _, _| {})? else {
            return Ok(climbed);
        };
        let net = self.setup.root().network_size()?;
        let (area, range) = (self.record.displayable_area, self.record.desired_range);
        let cam = self.calibration.camera_size();
        let plain: Vec<PrjImage> = (self.args.ntest..self.args.ntest + CONFIRM_IMAGES)
            .map(|i| {
                compend::patterns::sampling_image(
                    self.seed,
                    compend::patterns::Set::Test,
                    i,
                    net.width,
                    net.height,
                )
            })
            .collect();
        let views: Vec<CamImage> = plain
            .iter()
            .map(|x| compend::fov::place_in_area(&range.apply(x), area, cam))
            .collect::<compend::Result<_>>()?;
        let frames = rig::score::Frames::single(FRAMES_CONFIRM);
        let uncompensated = rig::closed_loop(
            self.calibration,
            &self.on_canvas(&plain)?,
            &views,
            area,
            frames,
        )?;
        let score = |m: &compend::model::Model| -> compend::Result<ClosedLoopScore> {
            let shown: Vec<PrjImage> = views
                .iter()
                .map(|z| m.infer(z).map(|x| x.into_space()))
                .collect::<compend::Result<_>>()?;
            let s = rig::closed_loop(
                self.calibration,
                &self.on_canvas(&shown)?,
                &views,
                area,
                frames,
            )?;
            let inputs: Vec<&CamImage> = views.iter().collect();
            let outputs: Vec<&PrjImage> = shown.iter().collect();
            let failure = compend::failure::classify(&inputs, &outputs, s.psnr, uncompensated.psnr);
            Ok(ClosedLoopScore {
                method: m.meta.method,
                psnr: s.psnr,
                ssim: s.ssim,
                // As a calibration's verification with its default margin.
                passed: compend::calibrate::passes(
                    failure,
                    s.psnr - uncompensated.psnr,
                    compend::calibrate::DEFAULT_MIN_GAIN_DB,
                ),
            })
        };
        let (su, sl) = (score(&climbed)?, score(&lower)?);
        let rule = fit::ClimbRule {
            gain_db: req.climb_gain_db.unwrap_or(fit::DEFAULT_RIG_GAIN_DB),
        };
        Ok(fit::settle_climb((climbed, su), (lower, sl), rule).0)
    }
}

/// Verification images of `auto`'s check on the rig (a calibration's default).
const CONFIRM_IMAGES: usize = 5;
/// Frame indices of those captures.
const FRAMES_CONFIRM: u64 = 4_000_000;

/// Across seeds, per scene × method × ntrain: the closed-loop PSNR and the gap to the oracle
/// as mean and range, and how many seeds failed (no model, or a failure class). Only when some
/// scene was run with more than one seed.
fn spread_table(rows: &[Row]) -> String {
    use std::collections::BTreeMap;
    let mut groups: BTreeMap<(&str, &str, Option<usize>), Vec<&Row>> = BTreeMap::new();
    for r in rows {
        groups
            .entry((r.scene.as_str(), r.method.as_str(), r.ntrain))
            .or_default()
            .push(r);
    }
    if groups.values().all(|g| g.len() < 2) {
        return String::new();
    }
    let mut md = String::from(
        "\nAcross seeds: closed-loop PSNR and gap to the oracle, mean (min–max); failed: seeds \
         whose model failed or was classified as failed.\n\n\
         | scene | method | #train | seeds | closed-loop PSNR | gap dB | failed |\n\
         |---|---|---|---|---|---|---|\n",
    );
    let stat = |v: &[f64]| -> String {
        if v.is_empty() {
            return "–".into();
        }
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        let (lo, hi) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            });
        format!("{mean:.2} ({lo:.2}–{hi:.2})")
    };
    for ((scene, method, ntrain), g) in groups {
        let psnr: Vec<f64> = g
            .iter()
            .filter_map(|r| r.closed_loop.map(|s| s.psnr))
            .collect();
        let gap: Vec<f64> = g.iter().filter_map(|r| r.gap_db).collect();
        let failed = g
            .iter()
            .filter(|r| r.failed.is_some() || r.failure.is_some())
            .count();
        let _ = writeln!(
            md,
            "| {scene} | {method} | {} | {} | {} | {} | {failed} |",
            train_label(ntrain, g[0].loop_pairs),
            g.len(),
            stat(&psnr),
            stat(&gap)
        );
    }
    md
}

/// A row's training pairs for the tables: `48`, or `48+48` with closed-loop pairs.
fn train_label(ntrain: Option<usize>, loops: Option<usize>) -> String {
    match (ntrain, loops) {
        (None, _) => "–".into(),
        (Some(n), None) => n.to_string(),
        (Some(n), Some(k)) => format!("{n}+{k}"),
    }
}

/// Tables: one row per scene × seed × method × ntrain, the spread across seeds, then what no
/// model can fix per scene and seed.
fn markdown(rows: &[Row], reach: &[SceneReach], device: fit::TrainDevice) -> String {
    let mut md = format!(
        "# compend bench\n\nThe CompenNet++ rungs trained on {device}. Closed loop: PSNR/SSIM of what the rig's camera sees inside the displayable \
         area against the desired image; gap: oracle PSNR minus the row's. Paper: the model's output \
         for test captures against the projector inputs (network space). A method marked \
         (diverged), (collapsed) or (worse than uncompensated) failed so; `auto → R` chose rung \
         R; #train `48+48`: sampling and closed-loop pairs (`--loop-images`).\n\n\
         | scene | seed | method | #train | train s | captures | ms/frame (CPU) | closed-loop PSNR | SSIM | gap dB | paper PSNR | paper SSIM |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let f = |v: Option<f64>, p: usize| v.map_or("–".to_string(), |x| format!("{x:.p$}"));
    for r in rows {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            r.scene,
            r.seed,
            match (&r.failed, r.failure, &r.chosen) {
                (Some(_), _, _) => format!("{} (failed)", r.method),
                (None, Some(f), _) => format!("{} ({f})", r.method),
                (None, None, Some(c)) => format!("{} → {c}", r.method),
                (None, None, None) => r.method.clone(),
            },
            train_label(r.ntrain, r.loop_pairs),
            f(r.train_seconds, 1),
            r.captures.map_or("–".into(), |n| n.to_string()),
            f(r.frame_ms_cpu, 1),
            f(r.closed_loop.map(|s| s.psnr), 2),
            f(r.closed_loop.map(|s| s.ssim), 3),
            f(r.gap_db, 2),
            f(r.paper.map(|s| s.psnr), 2),
            f(r.paper.map(|s| s.ssim), 3),
        );
    }
    let weighed: Vec<String> = rows
        .iter()
        .filter_map(|r| {
            let l = r.live.as_ref()?;
            Some(format!(
                "- {} seed {} `{}`: {}.\n",
                r.scene,
                r.seed,
                r.method,
                l.describe()
            ))
        })
        .collect();
    if !weighed.is_empty() {
        md.push_str("\n`auto`'s climb weighed against the display's frame budget:\n\n");
        md.push_str(&weighed.concat());
    }
    md.push_str(&spread_table(rows));
    md.push_str(
        "\nWhere no model can compensate (percent of the displayable area; \
         SETUP/cam/unreachable.png shows where): the projector does not reach the pixel \
         (shadowed), the camera clips under white (saturated), white stays below the top of \
         the desired range (too dark) or black above its bottom (too bright).\n\n\
         | scene | seed | unreachable % | shadowed % | saturated % | too dark % | too bright % |\n\
         |---|---|---|---|---|---|---|\n",
    );
    for r in reach {
        let u = &r.summary;
        let _ = writeln!(
            md,
            "| {} | {} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} |",
            r.scene,
            r.seed,
            u.unreachable_percent,
            u.shadowed_percent,
            u.saturated_percent,
            u.too_dark_percent,
            u.too_bright_percent
        );
    }
    md
}
