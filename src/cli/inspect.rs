//! `compend inspect --setup PATH [--data ROOT] [--json]`: checks a whole setup (every image of
//! every set of the setup and its data root is decoded and size-checked) and prints its summary.
//! Problems go to stderr, each naming its file and what was expected; any problem → exit 2.

use std::path::PathBuf;

use anyhow::Result;
use compend::dataset::{ImageSize, SetCounts, Setup, SetupInfo};
use serde::Serialize;

/// At most this many problems are listed (all are counted).
pub const MAX_PROBLEMS: usize = 50;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The setup folder, holding cam/raw/{ref,train,test,sl} (e.g. ROOT/light2/pos1/curves_np).
    #[arg(long)]
    pub setup: PathBuf,
    /// The data root holding train/ and test/ [default: the nearest ancestor of the setup that
    /// holds both].
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Print one JSON object on stdout instead of the human-readable summary.
    #[arg(long)]
    pub json: bool,
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
}

/// Opens the setup and checks it fully.
pub fn report(args: &Args) -> Result<Report> {
    let setup = Setup::open(&args.setup, args.data.as_deref())?;
    let v = setup.validate(MAX_PROBLEMS);
    Ok(Report {
        ok: v.is_ok(),
        setup: v.info,
        images_checked: v.images_checked,
        problems: v.problems.iter().map(|e| e.to_string()).collect(),
        total_problems: v.total_problems,
    })
}

pub fn run(args: Args) -> Result<()> {
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
        args.setup.display(),
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
    println!(
        "projector     {} (structured-light patterns)",
        size(s.projector_size)
    );
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
    if s.compensated.is_empty() {
        println!("compensated   none");
    } else {
        println!("compensated   {}", s.compensated.join(", "));
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
