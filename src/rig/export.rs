//! Writing a simulated setup in the dataset layout (docs/architecture.md, "Dataset layout"), so
//! the offline commands and other tools (such as the official PyTorch code) can read it.
//!
//! The projector-side images (`ROOT/train`, `test`, `ref`, `sl`) must already exist (`compend
//! patterns` writes them); this module captures them on the rig exactly as stored (8-bit PNGs),
//! placing network-size images on the canvas (the full projector frame) with bilinear resizing,
//! and showing structured light at projector resolution as is. It then finds the projector FOV
//! from the black and white captures the way a real setup would ([`crate::fov::fov_mask`]),
//! the optimal displayable area inside it, and writes the desired test images there.

use std::path::{Path, PathBuf};
use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::physics::{Phase, Simulator};
use super::scene::Scene;
use crate::dataset::{CaptureSet, DataRoot, ProjectorSet, Reference, Setup};
use crate::error::{Error, Result};
use crate::fov;
use crate::patterns::CUBE_COUNT;
use crate::pngio;
use crate::raster::{ImageSize, PrjImage, Rect};

/// Name of the file in the setup folder that records how the setup was simulated.
pub const RIG_FILE: &str = "rig.json";
/// Written in a setup before an export's first capture and removed once [`RIG_FILE`] is there:
/// an export that was interrupted may be run again over its own captures.
const EXPORTING_FILE: &str = ".exporting";

/// First frame index of each capture set: noise depends on the frame index, and fixed bases
/// keep, e.g., the test captures the same whatever the number of training images.
const FRAMES_REF: u64 = 0;
const FRAMES_SL: u64 = 10_000;
const FRAMES_TRAIN: u64 = 100_000;
const FRAMES_TEST: u64 = 1_000_000;
const FRAMES_LOOP: u64 = 200_000;

/// What [`export_setup`] captures.
#[derive(Clone, Debug, PartialEq)]
pub struct ExportOptions {
    /// Training images to capture (the first `ntrain` of `ROOT/train`).
    pub ntrain: usize,
    /// Test images to capture (the first `ntest` of `ROOT/test`), each with its desired image.
    pub ntest: usize,
    /// Capture every colour-cube image of `ROOT/ref` (else only black and white) and the gray
    /// image.
    pub full_cube: bool,
    /// Capture the structured-light patterns of `ROOT/sl` when present.
    pub structured_light: bool,
    /// The camera-value range the desired images are scaled into.
    pub desired_range: DesiredScaling,
}

/// How [`export_setup`] scales the test images into desired images (camera values, 0–1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum DesiredScaling {
    /// Into the range the projector reaches across the displayable area, found from this
    /// export's black and white captures ([`fov::display_range`]).
    Reachable,
    /// Unscaled (`{low: 0, high: 1}`).
    Full,
    /// Into a given range, e.g. the one `compend calibrate` found for a model (from captures
    /// averaged over several frames, so a little wider than one noisy frame gives).
    Given(fov::DisplayRange),
}

/// Record of a simulated setup (`SETUP/rig.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RigRecord {
    /// The scene as simulated (resolutions included).
    pub scene: Scene,
    pub seed: u64,
    /// Projector pose the captures were taken with.
    pub phase: Phase,
    /// The canvas in projector pixels (where network-size images were placed).
    pub canvas: Rect,
    /// The displayable area in camera pixels (where `cam/desire/test` images were placed).
    pub displayable_area: Rect,
    /// The camera-value range desired images were scaled into (`{low: 0, high: 1}` = unscaled).
    #[serde(default = "full_range")]
    pub desired_range: fov::DisplayRange,
    /// Fraction of the camera frame in the FOV mask found from the captures.
    pub fov_coverage: f64,
    /// Fraction of the camera frame truly lit by the projector (the simulator's ground truth).
    pub true_fov_coverage: f64,
    /// Counts of captures written.
    pub ref_captures: usize,
    pub sl_captures: usize,
    pub train_captures: usize,
    pub test_captures: usize,
}

/// What [`export_setup`] wrote.
#[derive(Clone, Debug)]
pub struct ExportSummary {
    pub setup: PathBuf,
    pub record: RigRecord,
    pub seconds: f64,
}

/// Whether an export may write the setup `setup` under the data root `root`: over an earlier
/// export (its scene and seed made it; `rig.json` beside it, or the marker of one that was
/// interrupted), but never over captures that did not come from one (a calibration's, a
/// recorded data set's): an input error naming the folder.
pub fn check_setup_free(root: &Path, setup: &Path) -> Result<()> {
    let dir = root.join(setup);
    let raw = dir.join("cam").join("raw");
    let holds_captures = std::fs::read_dir(&raw).is_ok_and(|mut d| d.next().is_some());
    let exported = dir.join(RIG_FILE).is_file() || dir.join(EXPORTING_FILE).is_file();
    if holds_captures && !exported {
        return Err(Error::Input(format!(
            "{}: holds captures that no export made (no {RIG_FILE}), a calibration's or a \
             recorded set's, which are never replaced: export into another folder",
            dir.display()
        )));
    }
    Ok(())
}

/// The full projector frame as a canvas.
pub fn full_canvas(sim: &Simulator) -> Rect {
    Rect::covering(sim.projector_size())
}

/// Captures a complete setup at `root/<setup>` (created) with the simulator's current phase:
/// reference captures (black, white, gray surface image, and the colour cube with
/// `full_cube`), structured light, training and test captures, and the desired test images in
/// the displayable area; finally `rig.json`. Every file is a pure function of the simulator
/// (scene and seed) and the projector-side images, so equal inputs give byte-identical files.
pub fn export_setup(
    sim: &Simulator,
    root: &DataRoot,
    setup: &Path,
    opts: &ExportOptions,
) -> Result<ExportSummary> {
    let start = Instant::now();
    let net = root.network_size()?;
    check_setup_free(root.path(), setup)?;
    let setup = Setup::create(root, setup)?;
    let exporting = setup.path().join(EXPORTING_FILE);
    crate::files::write_atomically(&exporting, b"a `compend sim export` under way\n")?;
    let rig = Capturing {
        sim,
        root,
        setup,
        canvas: full_canvas(sim),
        psize: sim.projector_size(),
        net,
        net_why: format!("the network size of {}", root.path().display()),
    };
    let nref = rig.references(opts.full_cube)?;
    let nsl = if opts.structured_light && root.image_path(ProjectorSet::Sl, 1).is_file() {
        rig.structured_light()?
    } else {
        0
    };
    rig.pairs(opts.ntrain, opts.ntest)?;
    let (fov, area, range) = rig.desired(opts.ntest, opts.desired_range)?;

    let cam = sim.camera_size();
    let frame = (cam.width * cam.height) as f64;
    let record = RigRecord {
        scene: sim.scene().clone(),
        seed: sim.seed(),
        phase: sim.phase(),
        canvas: rig.canvas,
        displayable_area: area,
        desired_range: range,
        fov_coverage: fov.mask.count() as f64 / frame,
        true_fov_coverage: sim.lit_mask().count() as f64 / frame,
        ref_captures: nref,
        sl_captures: nsl,
        train_captures: opts.ntrain,
        test_captures: opts.ntest,
    };
    write_record(&rig.setup, &record)?;
    std::fs::remove_file(&exporting).map_err(|e| Error::io(&exporting, "remove", e))?;
    Ok(ExportSummary {
        setup: rig.setup.path().to_path_buf(),
        record,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// The rig capturing the projector-side images of a data root into one setup.
struct Capturing<'a> {
    sim: &'a Simulator,
    root: &'a DataRoot,
    setup: Setup,
    /// Where network-size images are stretched (projector pixels): the full frame.
    canvas: Rect,
    /// Projector size, (width, height) pixels.
    psize: ImageSize,
    /// Network size of the root's images, (width, height) pixels, and why (for size errors).
    net: ImageSize,
    net_why: String,
}

impl Capturing<'_> {
    /// A projector-side network-size image, as the projector shows it on the canvas.
    fn shown(&self, set: ProjectorSet, i: usize) -> Result<PrjImage> {
        let p = self.root.image_path(set, i);
        let img = pngio::read_rgb_sized::<crate::raster::Projector>(&p, self.net, &self.net_why)?;
        crate::playback::place_on_canvas(&img, self.canvas, self.psize)
    }

    /// References: black (cube 1), white (cube 125), optionally the rest of the cube; gray.
    /// Returns the number of reference captures written.
    fn references(&self, full_cube: bool) -> Result<usize> {
        let cube: Vec<usize> = if full_cube {
            (1..=CUBE_COUNT).collect()
        } else {
            vec![Reference::Black.index(), Reference::White.index()]
        };
        cube.par_iter().try_for_each(|&i| -> Result<()> {
            let cap = self
                .sim
                .capture(&self.shown(ProjectorSet::Ref, i)?, FRAMES_REF + i as u64)?;
            self.setup.write_capture(CaptureSet::Ref, i, &cap).map(drop)
        })?;
        let gray_path = self.root.gray_input_path();
        let gray =
            pngio::read_rgb_sized::<crate::raster::Projector>(&gray_path, self.net, &self.net_why)?;
        let cap = self.sim.capture(
            &crate::playback::place_on_canvas(&gray, self.canvas, self.psize)?,
            FRAMES_REF + Reference::Gray.index() as u64,
        )?;
        self.setup.write_reference(Reference::Gray, &cap)?;
        Ok(cube.len() + 1)
    }

    /// Structured light at projector resolution, shown as is. Returns the number of patterns.
    fn structured_light(&self) -> Result<usize> {
        let nsl = self.root.count(ProjectorSet::Sl)?;
        let why = format!("the projector size of scene {:?}", self.sim.scene().name);
        (1..=nsl).into_par_iter().try_for_each(|i| -> Result<()> {
            let p = self.root.image_path(ProjectorSet::Sl, i);
            let img = pngio::read_rgb_sized(&p, self.psize, &why)?;
            let cap = self.sim.capture(&img, FRAMES_SL + i as u64)?;
            self.setup.write_capture(CaptureSet::Sl, i, &cap).map(drop)
        })?;
        Ok(nsl)
    }

    /// Training and test captures: the first `ntrain` and `ntest` images of the root.
    fn pairs(&self, ntrain: usize, ntest: usize) -> Result<()> {
        for (set, cset, n, base) in [
            (ProjectorSet::Train, CaptureSet::Train, ntrain, FRAMES_TRAIN),
            (ProjectorSet::Test, CaptureSet::Test, ntest, FRAMES_TEST),
        ] {
            let have = self.root.count(set)?;
            if have < n {
                return Err(Error::Input(format!(
                    "{}: {have} projector images, {n} requested",
                    self.root.dir(set).display()
                )));
            }
            (1..=n).into_par_iter().try_for_each(|i| -> Result<()> {
                let cap = self.sim.capture(&self.shown(set, i)?, base + i as u64)?;
                self.setup.write_capture(cset, i, &cap).map(drop)
            })?;
        }
        Ok(())
    }

    /// FOV and displayable area (camera pixels) from the captures, as a real setup finds them;
    /// the first `ntest` test images placed in the area as desired images, scaled as `scaling`
    /// says.
    fn desired(
        &self,
        ntest: usize,
        scaling: DesiredScaling,
    ) -> Result<(fov::FovMask, Rect, fov::DisplayRange)> {
        let setup = &self.setup;
        let black = setup.load_reference(Reference::Black)?;
        let white = setup.load_reference(Reference::White)?;
        let label = setup.capture_dir(CaptureSet::Ref).display().to_string();
        let fov = fov::fov_mask(&black, &white, &label)?;
        let aspect = self.canvas.width as f64 / self.canvas.height as f64;
        let area = fov::displayable_area(&fov.mask, aspect)?;
        let range = match scaling {
            DesiredScaling::Reachable => {
                fov::display_range(&black, &white, area, fov::DESIRED_RANGE_QUANTILE)?
            }
            DesiredScaling::Full => fov::DisplayRange::FULL,
            DesiredScaling::Given(r) => r,
        };
        let cam = self.sim.camera_size();
        (1..=ntest)
            .into_par_iter()
            .try_for_each(|i| -> Result<()> {
                let p = self.root.image_path(ProjectorSet::Test, i);
                let img =
                    pngio::read_rgb_sized::<crate::raster::Projector>(&p, self.net, &self.net_why)?;
                let z = fov::place_in_area(&range.apply(&img), area, cam)?;
                setup.write_desired(i, &z).map(drop)
            })?;
        Ok((fov, area, range))
    }
}

/// Closed-loop pairs on the rig, as `compend calibrate` takes them
/// ([`crate::calibrate::refine`]), for an exported setup: for i in 1..=`n`, sampling image
/// `1 + (i − 1) % ntrain` of the root, scaled into the record's desired range and placed in its
/// displayable area, is a desired view d (camera pixels). `model`'s compensation of d (network
/// size, 8-bit) is written to the root as training image `ntrain + i`, d to the setup's
/// `cam/desire/train`, and the rig's capture of it (frames from their own base, so equal inputs
/// give equal files) as the pair's capture. `ntrain` must be the number of sampling images the
/// export captured; training image `ntrain + i` is replaced.
pub fn export_loop_pairs(
    sim: &Simulator,
    setup: &Setup,
    record: &RigRecord,
    model: &crate::model::Model,
    (ntrain, n): (usize, usize),
) -> Result<()> {
    let root = setup.root();
    if ntrain == 0 {
        return Err(Error::Input(
            "closed-loop pairs need at least one sampling image".into(),
        ));
    }
    (1..=n).into_par_iter().try_for_each(|i| -> Result<()> {
        let (desired, shown) = crate::calibrate::loop_image(
            root,
            (ntrain, i),
            (record.desired_range, record.displayable_area),
            model,
        )?;
        root.write(ProjectorSet::Train, ntrain + i, &shown)?;
        setup.write_loop_desired(ntrain + i, &desired)?;
        let frame = crate::playback::place_on_canvas(&shown, record.canvas, sim.projector_size())?;
        let cap = sim.capture(&frame, FRAMES_LOOP + i as u64)?;
        setup.write_capture(CaptureSet::Train, ntrain + i, &cap)?;
        Ok(())
    })
}

/// Refuses, before anything is written, an export whose closed-loop pairs (`n` of them after
/// `ntrain` sampling pairs; `n` = 0: none) would not match the files around them: closed-loop
/// pairs the setup `setup` (a folder under `root`) holds outside `ntrain + 1 ..= ntrain + n`
/// (an earlier export's, whose captures this one replaces), and, with `n` > 0, another setup
/// of the root with closed-loop pairs (they share the root's training images after the
/// sampling ones).
pub fn check_loop_slots(root: &Path, setup: &Path, ntrain: usize, n: usize) -> Result<()> {
    let ours = root.join(setup);
    let desire = |dir: &Path| crate::dataset::loop_desired_dir(dir);
    let stale = crate::dataset::scan_indices(&desire(&ours))?
        .into_iter()
        .find(|&i| i <= ntrain || i > ntrain + n);
    if let Some(i) = stale {
        return Err(Error::Input(format!(
            "{}: the desired view of a closed-loop pair an earlier export took, which this \
             export's captures would no longer match; remove {} or export into another --out",
            desire(&ours).join(pngio::indexed_name(i)).display(),
            desire(&ours).display()
        )));
    }
    if n == 0 {
        return Ok(());
    }
    let entries = match std::fs::read_dir(root) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(Error::io(root, "list folder", e)),
    };
    for entry in entries {
        let other = entry.map_err(|e| Error::io(root, "list folder", e))?.path();
        if other != ours && desire(&other).is_dir() {
            return Err(Error::Input(format!(
                "{}: another setup's closed-loop pairs use {} after the sampling images; export \
                 closed-loop pairs into another --out",
                desire(&other).display(),
                root.join(ProjectorSet::Train.dir_name()).display()
            )));
        }
    }
    Ok(())
}

/// Writes `SETUP/rig.json`.
fn write_record(setup: &Setup, record: &RigRecord) -> Result<()> {
    let path = setup.path().join(RIG_FILE);
    let json = serde_json::to_string_pretty(record)
        .map_err(|e| Error::Failed(format!("{}: cannot encode the record: {e}", path.display())))?;
    crate::files::write_atomically(&path, json.as_bytes())
}

/// Reads `SETUP/rig.json`.
pub fn read_record(setup: &Path) -> Result<RigRecord> {
    let path = setup.join(RIG_FILE);
    let text = crate::files::read_text(&path, "a virtual-rig record (JSON)")?;
    serde_json::from_str(&text).map_err(|e| {
        Error::Input(format!(
            "{}: not a virtual-rig record ({e})",
            path.display()
        ))
    })
}

fn full_range() -> fov::DisplayRange {
    fov::DisplayRange::FULL
}
