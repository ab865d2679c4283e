//! `compend inspect --setup PATH [--data ROOT] [--json]`: checks a whole setup (every image of
//! every set of the setup and its data root is decoded and size-checked) and prints its summary.
//! Problems go to stderr, each naming its file and what was expected; any problem → exit 2.

use std::path::PathBuf;

use anyhow::Result;
use compend::dataset::{Reference, SetCounts, Setup, SetupInfo};
use compend::raster::ImageSize;
use compend::raster::{CamImage, Camera, Mask, Rect};
use serde::Serialize;

/// At most this many problems are listed (all are counted).
pub const MAX_PROBLEMS: usize = 50;

#[derive(clap::Args, Debug)]
pub struct Args {
    #[command(flatten)]
    pub setup: super::SetupArgs,
    /// Print one JSON object on stdout instead of the human-readable summary.
    #[arg(long)]
    pub json: bool,
    /// Write the projector FOV mask (fov_mask.png) and an overlay of the mask, its bounding box
    /// and the displayable area on the white capture (fov_overlay.png), and where no model can
    /// compensate (unreachable.png: blue shadowed, magenta saturated, red too dark, yellow too
    /// bright) into this folder.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Canvas aspect ratio (width/height) for the displayable area [default: the projector's,
    /// from its structured-light patterns or the calibration's record, as `calibrate` and `play`
    /// use; else the network image's].
    #[arg(long, value_parser = parse_aspect)]
    pub aspect: Option<f64>,
}

/// `--aspect`: a width over height that a rectangle can have.
fn parse_aspect(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(a) if a.is_finite() && (0.01..=100.0).contains(&a) => Ok(a),
        _ => Err(format!(
            "expected a width over height from 0.01 to 100 (e.g. 1.333), got {s:?}"
        )),
    }
}

/// The projector's field of view as seen by the camera, from the black and white references.
#[derive(Debug, Serialize)]
pub struct FovReport {
    /// Bounding box of the FOV mask, camera pixels.
    pub bbox: compend::raster::Rect,
    /// Fraction of the camera frame inside the mask.
    pub coverage: f64,
    /// Largest rectangle of the canvas aspect inside the mask, camera pixels.
    pub displayable_area: Option<compend::raster::Rect>,
    pub aspect: f64,
    /// The share of the displayable area no model can compensate (against the display range
    /// calibration would choose), and why.
    pub unreachable: Option<compend::fov::ReachSummary>,
    pub diagnostics: compend::fov::FovDiagnostics,
}

/// What `inspect` reports: the setup summary, then the outcome of the full check.
#[derive(Debug, Serialize)]
pub struct Report {
    /// True when no problem was found.
    pub ok: bool,
    #[serde(flatten)]
    pub setup: SetupInfo,
    /// Number of image files decoded and size-checked.
    pub images_checked: usize,
    /// The problems found (at most [`MAX_PROBLEMS`]), each naming its file.
    pub problems: Vec<String>,
    /// Number of problems found, including those not listed.
    pub total_problems: usize,
    /// The projector's size, and where it was read: the structured-light patterns, or the
    /// record of the calibration that made the setup; `None` when neither says.
    pub projector: Option<ImageSize>,
    pub projector_from: Option<&'static str>,
    /// The FOV analysis, when the black and white references are readable.
    pub fov: Option<FovReport>,
}

/// The projector's size and where it was read: its structured-light patterns (`sl_size`, the
/// data root's), else what the calibration that made the setup recorded (a manifest that
/// cannot be read is reported with the closed-loop pairs' check).
fn projector(
    setup: &Setup,
    sl_size: Option<ImageSize>,
) -> (Option<ImageSize>, Option<&'static str>) {
    match sl_size {
        Some(p) => (Some(p), Some("structured-light patterns")),
        None => match compend::dataset::manifest::recorded_projector(setup.path()) {
            Ok(Some(p)) => (Some(p), Some("recorded by the calibration")),
            _ => (None, None),
        },
    }
}

/// Opens the setup and checks it fully.
pub fn report(args: &Args) -> Result<Report> {
    let setup = args.setup.open()?;
    // Every problem is kept until the others are added, so that none is counted twice; at most
    // MAX_PROBLEMS are listed.
    let v = setup.validate(usize::MAX);
    let mut problems: Vec<String> = v.problems.iter().map(|e| e.to_string()).collect();
    // A calibration's closed-loop pairs start right after its sampling pairs (its manifest
    // says how many): a lost first view is a problem here too. An error the validation already
    // reported (an unreadable folder, a gap) is not counted twice.
    let checked = setup
        .count(compend::dataset::CaptureSet::Train)
        .and_then(|n| compend::dataset::manifest::checked_loop_pairs(&setup, n, None));
    if let Err(e) = checked {
        let e = e.to_string();
        if !problems.contains(&e) {
            problems.push(e);
        }
    }
    let (projector, projector_from) = projector(&setup, v.info.projector_size);
    let fov = match fov_report(&setup, args, projector) {
        Ok(f) => f,
        Err(e) => {
            // A setup whose projector light cannot be found is not usable: report it as a problem.
            problems.push(format!("{e:#}"));
            None
        }
    };
    let total_problems = problems.len();
    problems.truncate(MAX_PROBLEMS);
    Ok(Report {
        ok: total_problems == 0,
        setup: v.info,
        images_checked: v.images_checked,
        problems,
        total_problems,
        projector,
        projector_from,
        fov,
    })
}

/// FOV mask and displayable area; `None` when a reference is unreadable (already a problem).
fn fov_report(
    setup: &Setup,
    args: &Args,
    projector: Option<ImageSize>,
) -> Result<Option<FovReport>> {
    let (Ok(black), Ok(white)) = (
        setup.load_reference(Reference::Black),
        setup.load_reference(Reference::White),
    ) else {
        return Ok(None);
    };
    let label = format!(
        "{} and {}",
        setup.reference_path(Reference::Black).display(),
        setup.reference_path(Reference::White).display()
    );
    let fov = compend::fov::fov_mask(&black, &white, &label)?;
    let aspect = match (args.aspect, projector) {
        (Some(a), _) => a,
        (None, Some(p)) => p.aspect(),
        (None, None) => setup
            .root()
            .network_size()
            .map(ImageSize::aspect)
            .unwrap_or(1.0),
    };
    let area = compend::fov::displayable_area(&fov.mask, aspect).ok();
    // The display range fails when too little of the area responds: then there is no reach.
    let reach = area.and_then(|a| {
        let range =
            compend::fov::display_range(&black, &white, a, compend::fov::DESIRED_RANGE_QUANTILE)
                .ok()?;
        compend::fov::reach(&black, &white, a, range).ok()
    });
    if let Some(dir) = &args.out {
        compend::pngio::write_mask(&dir.join("fov_mask.png"), &fov.mask)?;
        let overlay = overlay(&white, &fov.mask, fov.bbox, area);
        compend::pngio::write_rgb(&dir.join("fov_overlay.png"), &overlay)?;
        if let Some(r) = &reach {
            compend::pngio::write_rgb(&dir.join("unreachable.png"), &r.picture(&white)?)?;
        }
    }
    Ok(Some(FovReport {
        bbox: fov.bbox,
        coverage: fov.diagnostics.coverage,
        displayable_area: area,
        aspect,
        unreachable: reach.map(|r| r.summary()),
        diagnostics: fov.diagnostics,
    }))
}

/// The white capture dimmed outside the mask, the bounding box in red, the area in green.
fn overlay(white: &CamImage, mask: &Mask<Camera>, bbox: Rect, area: Option<Rect>) -> CamImage {
    let mut out = CamImage::from_fn(white.width(), white.height(), |x, y| {
        let p = white.get(x, y);
        if mask.get(x, y) {
            p
        } else {
            p.map(|v| 0.3 * v)
        }
    });
    let mut frame = |r: Rect, colour: [f32; 3]| {
        for x in r.x..r.x + r.width {
            out.set(x, r.y, colour);
            out.set(x, r.y + r.height - 1, colour);
        }
        for y in r.y..r.y + r.height {
            out.set(r.x, y, colour);
            out.set(r.x + r.width - 1, y, colour);
        }
    };
    frame(bbox, [1.0, 0.0, 0.0]);
    if let Some(a) = area {
        frame(a, [0.0, 1.0, 0.0]);
    }
    out
}

pub fn run(args: Args) -> Result<()> {
    if let Some(dir) = &args.out {
        // Only pictures an earlier `inspect` wrote there are replaced.
        let names: Vec<String> = ["fov_mask.png", "fov_overlay.png", "unreachable.png"]
            .map(String::from)
            .to_vec();
        let mut owned =
            super::OwnedOut::open(dir, "--out", ".compend-inspected", "compend inspect")?;
        owned.check(&names)?;
        owned.claim(&names)?;
    }
    let r = report(&args)?;
    if args.json {
        println!("{}", serde_json::to_string(&r)?);
    } else {
        print_human(&r);
    }
    if r.ok {
        return Ok(());
    }
    for p in &r.problems {
        eprintln!("compend: {p}");
    }
    if r.total_problems > r.problems.len() {
        eprintln!(
            "compend: ... and {} more problems",
            r.total_problems - r.problems.len()
        );
    }
    Err(compend::Error::Input(format!(
        "{}: {} problem{} found in the setup or its data root",
        args.setup.setup.display(),
        r.total_problems,
        if r.total_problems == 1 { "" } else { "s" }
    ))
    .into())
}

fn print_human(r: &Report) {
    let s = &r.setup;
    let size = |x: Option<ImageSize>| x.map_or_else(|| "unknown".to_string(), |x| x.to_string());
    let yes = |b: bool| if b { "yes" } else { "MISSING" };
    println!("data root     {}", s.root.display());
    println!("setup         {}", s.setup.display());
    println!("camera size   {}", size(s.camera_size));
    println!("network size  {}", size(s.network_size));
    match r.projector_from {
        Some(from) => println!("projector     {} ({from})", size(r.projector)),
        None => {
            println!("projector     unknown (no structured-light patterns, no calibration record)")
        }
    }
    println!(
        "references    black {}, white {}, gray surface {}",
        yes(s.references.black),
        yes(s.references.white),
        yes(s.references.gray)
    );
    println!("              projector images   captures");
    let row = |name: &str, c: &SetCounts, f: fn(&SetCounts) -> usize| {
        println!("  {name:<12}{:>16}{:>11}", f(c), f(&s.captures));
    };
    let p = &s.projector_images;
    row("train", p, |c| c.train);
    row("test", p, |c| c.test);
    row("ref", p, |c| c.refs);
    row("sl", p, |c| c.sl);
    println!(
        "gray input    {}",
        if s.gray_input {
            "ref/img_gray.png"
        } else {
            "absent"
        }
    );
    match s.desired_test {
        Some(n) => println!("desired test  {n}"),
        None => println!("desired test  absent"),
    }
    if let (Some(first), Some(last)) = (s.loop_pairs.first(), s.loop_pairs.last()) {
        println!(
            "closed loop   {} pairs (train {first}–{last}, desired views in cam/desire/train)",
            s.loop_pairs.len()
        );
    }
    if s.compensated.is_empty() {
        println!("compensated   none");
    } else {
        println!("compensated   {}", s.compensated.join(", "));
    }
    if let Some(f) = &r.fov {
        println!(
            "projector FOV {:.1}% of the camera frame, bounding box {}",
            100.0 * f.coverage,
            f.bbox
        );
        match f.displayable_area {
            Some(a) => println!("display area  {a} (aspect {:.3})", f.aspect),
            None => println!("display area  none fits (aspect {:.3})", f.aspect),
        }
        if let Some(u) = &f.unreachable {
            println!("reach         {}", u.line());
        }
    }
    println!(
        "checked       {} images, {}",
        r.images_checked,
        if r.ok {
            "no problems".to_string()
        } else {
            format!("{} problems (listed on stderr)", r.total_problems)
        }
    );
}
