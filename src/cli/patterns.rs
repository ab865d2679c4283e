//! `compend patterns --out ROOT`: writes the projector-side images of a dataset
//! (docs/architecture.md, "Dataset layout"): `train/` and `test/` sampling images and `ref/`
//! (colour cube and gray image) at network size, `sl/` Gray-code structured light at projector
//! resolution.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use anyhow::{Context, Result};
use compend::dataset::{DataRoot, ProjectorSet};
use compend::patterns::{self, CUBE_COUNT, GrayCode, Set};
use compend::raster::ImageSize;
use rayon::prelude::*;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Data root to write into: ROOT/train, ROOT/test, ROOT/ref and ROOT/sl (created as needed).
    /// An image already there is kept when it is the one to be written, and refused otherwise
    /// (a root's captures were taken of its images).
    #[arg(long)]
    pub out: PathBuf,
    /// Number of training sampling images (ROOT/train/img_0001.png …).
    #[arg(long, default_value_t = 500, value_parser = clap::value_parser!(u64).range(1..=9999))]
    pub ntrain: u64,
    /// Number of test images (ROOT/test/img_0001.png …).
    #[arg(long, default_value_t = 200, value_parser = clap::value_parser!(u64).range(1..=9999))]
    pub ntest: u64,
    /// Seed of the sampling images (train and test are independent streams of it).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Network size of the sampling and reference images: N (square) or WxH, sides divisible by 4.
    #[arg(long, default_value = "256", value_name = "N|WxH", value_parser = parse_network_size)]
    pub size: ImageSize,
    /// Projector resolution of the structured-light patterns, WxH.
    #[arg(long, default_value = "800x600", value_name = "WxH", value_parser = parse_projector_size)]
    pub projector: ImageSize,
    /// 8-bit level of the gray image ROOT/ref/img_gray.png (the surface image x0).
    #[arg(long, default_value_t = patterns::DEFAULT_GRAY_LEVEL)]
    pub gray_level: u8,
}

/// Parses `WxH` (or `N` for a square when `square_ok`), both sides at least 1.
pub fn parse_wxh(s: &str, square_ok: bool) -> std::result::Result<ImageSize, String> {
    ImageSize::parse(s, square_ok)
}

fn parse_network_size(s: &str) -> std::result::Result<ImageSize, String> {
    let size = parse_wxh(s, true)?;
    if size.width % 4 != 0 || size.height % 4 != 0 {
        return Err(format!(
            "network size {size}: width and height must be divisible by 4 (e.g. 256 or 320x240)"
        ));
    }
    Ok(size)
}

fn parse_projector_size(s: &str) -> std::result::Result<ImageSize, String> {
    parse_wxh(s, false)
}

pub fn run(args: Args) -> Result<()> {
    let start = Instant::now();
    let root = DataRoot::create(&args.out)?;
    let net = args.size;
    let (ntrain, ntest) = (args.ntrain as usize, args.ntest as usize);
    eprintln!(
        "patterns: writing to {} (seed {}, network size {net}, projector {})",
        root.path().display(),
        args.seed,
        args.projector
    );

    for (set, n) in [(Set::Train, ntrain), (Set::Test, ntest)] {
        parallel(n, set.folder(), |i| {
            let img = patterns::sampling_image(args.seed, set, i, net.width, net.height);
            root.write_new(set.projector_set(), i + 1, &img)
        })?;
        warn_extra(&root.dir(set.projector_set()), n);
    }

    parallel(CUBE_COUNT, "ref", |i| {
        let img = patterns::color_cube(i + 1, net.width, net.height)?;
        root.write_new(ProjectorSet::Ref, i + 1, &img)
    })?;
    let gray = patterns::gray_image(args.gray_level, net.width, net.height);
    root.write_new_gray_input(&gray)?;
    warn_extra(&root.dir(ProjectorSet::Ref), CUBE_COUNT);

    let code = GrayCode::new(args.projector.width, args.projector.height)?;
    parallel(code.len(), "sl", |i| {
        root.write_new(ProjectorSet::Sl, i + 1, &code.pattern(i)?)
    })?;
    warn_extra(&root.dir(ProjectorSet::Sl), code.len());

    eprintln!(
        "patterns: wrote {ntrain} train and {ntest} test images ({net}), {CUBE_COUNT} colour cube \
         images and the gray image (level {}/255), {} structured-light patterns ({}: {} column + \
         {} row bits) to {} in {:.1} s",
        args.gray_level,
        code.len(),
        args.projector,
        code.col_bits(),
        code.row_bits(),
        root.path().display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Runs `job(0..n)` in parallel (the images are independent), printing progress for `label` on
/// stderr. Returns the first error.
fn parallel(
    n: usize,
    label: &str,
    job: impl Fn(usize) -> compend::Result<()> + Sync + Send,
) -> Result<()> {
    let done = AtomicUsize::new(0);
    let step = (n / 10).max(50);
    (0..n)
        .into_par_iter()
        .try_for_each(|i| {
            job(i)?;
            let d = done.fetch_add(1, Ordering::Relaxed) + 1;
            if d.is_multiple_of(step) && d < n {
                eprintln!("patterns: {label} {d}/{n}");
            }
            Ok::<(), compend::Error>(())
        })
        .with_context(|| format!("writing the {label} images"))?;
    eprintln!("patterns: {label} {n}/{n}");
    Ok(())
}

/// Warns when `dir` holds numbered images beyond the `n` just written (left from an earlier,
/// larger run): readers that count files would see a different set.
fn warn_extra(dir: &Path, n: usize) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let extra = entries
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let num = name
                .strip_prefix("img_")?
                .strip_suffix(".png")?
                .parse::<usize>();
            num.ok().filter(|&k| k > n)
        })
        .count();
    if extra > 0 {
        eprintln!(
            "patterns: warning: {} holds {extra} more numbered image(s) beyond img_{n:04}.png from an earlier run; remove them if they do not belong to this set",
            dir.display()
        );
    }
}
