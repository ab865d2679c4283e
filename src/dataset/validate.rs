//! The whole-setup check behind [`Setup::info`] and [`Setup::validate`] (docs/architecture.md,
//! "Dataset layout"): scans every folder of the root and the setup, reads every image (header
//! only, or fully decoded) and checks its size against the size of its space, collecting every
//! problem instead of stopping at the first. Sizes are (width, height) in pixels of the space
//! named.

use std::path::{Path, PathBuf};

use super::info::{References, SetCounts, SetupInfo};
use super::load::par_map;
use super::names::{Scan, check_loop_views, scan};
use super::root::{DataRoot, ProjectorSet};
use super::setup::{CaptureSet, Reference, Setup};
use crate::error::{Error, Result};
use crate::pngio;
use crate::raster::{ImageSize, Unspecified};

/// The result of [`Setup::validate`]: the summary as far as it could be worked out, and the
/// problems found (each an error naming its file and what was expected).
#[derive(Debug)]
pub struct Validation {
    pub info: SetupInfo,
    /// The first problems found, in a fixed order (root sets, references, capture sets, desired,
    /// compensation images, then cross-checks), at most the cap given.
    pub problems: Vec<Error>,
    /// Number of problems found, including those beyond the cap.
    pub total_problems: usize,
    /// Number of image files read.
    pub images_checked: usize,
}

impl Validation {
    pub fn is_ok(&self) -> bool {
        self.total_problems == 0
    }
}

impl Setup {
    /// Header-level summary: counts, sizes, references, models. Every file's header is read and
    /// size-checked; the first problem found is returned as the error. For a full check that
    /// decodes every image and reports every problem, use [`Setup::validate`].
    pub fn info(&self) -> Result<SetupInfo> {
        let mut v = survey(self, false, 1);
        match v.problems.drain(..).next() {
            Some(e) => Err(e),
            None => Ok(v.info),
        }
    }

    /// Full check: every image of every set (root and setup) is decoded and size-checked.
    /// Returns the summary (as far as it could be worked out) with every problem found; at most
    /// `max_problems` are kept, [`Validation::total_problems`] counts them all.
    pub fn validate(&self, max_problems: usize) -> Validation {
        survey(self, true, max_problems)
    }
}

struct Problems {
    kept: Vec<Error>,
    total: usize,
    cap: usize,
}

impl Problems {
    fn push(&mut self, e: Error) {
        self.total += 1;
        if self.kept.len() < self.cap {
            self.kept.push(e);
        }
    }

    /// Scans a folder, recording listing errors and (unless `gaps_allowed`) a gap.
    fn scan(&mut self, dir: &Path, gaps_allowed: bool) -> Scan {
        match scan(dir) {
            Ok(s) => {
                if !gaps_allowed && let Some(e) = s.gap(dir) {
                    self.push(e);
                }
                s
            }
            Err(e) => {
                self.push(e);
                Scan::default()
            }
        }
    }
}

/// The size every image of a group must have, and why.
#[derive(Clone)]
struct Expect {
    size: ImageSize,
    why: String,
}

fn paths_of(dir: &Path, s: &Scan) -> Vec<PathBuf> {
    s.indices
        .iter()
        .map(|&i| dir.join(pngio::indexed_name(i)))
        .collect()
}

/// The size of `primary` when its header reads, else of the first readable image in `paths`.
fn space_size(
    primary: Option<(PathBuf, String)>,
    paths: &[PathBuf],
    space: &str,
) -> Option<Expect> {
    if let Some((p, why)) = &primary
        && p.is_file()
        && let Ok(size) = pngio::png_size(p)
    {
        // The primary sets the size unless most of the other images disagree with it: then it
        // is the odd one out, and the majority's size is the one to check against.
        let others: Vec<ImageSize> = paths
            .iter()
            .filter(|q| *q != p)
            .filter_map(|q| pngio::png_size(q).ok())
            .collect();
        let majority = others
            .iter()
            .copied()
            .find(|&m| m != size && 2 * others.iter().filter(|&&o| o == m).count() > others.len());
        return Some(match majority {
            Some(m) => Expect {
                size: m,
                why: format!(
                    "the {space} size of {} of the {} {space} images; {} differs from them",
                    others.iter().filter(|&&o| o == m).count(),
                    others.len(),
                    p.display()
                ),
            },
            None => Expect {
                size,
                why: why.clone(),
            },
        });
    }
    let missing = primary
        .map(|(p, _)| format!("{} is absent or unreadable", p.display()))
        .unwrap_or_else(|| "nothing sets it".into());
    paths.iter().find_map(|p| {
        let size = pngio::png_size(p).ok()?;
        Some(Expect {
            size,
            why: format!(
                "the {space} size of the first readable {space} image {}, since {missing}",
                p.display()
            ),
        })
    })
}

fn check_file(path: &Path, expect: Option<&Expect>, decode: bool) -> Result<(), Error> {
    let size = if decode {
        pngio::read_rgb::<Unspecified>(path)?.size()
    } else {
        pngio::png_size(path)?
    };
    match expect {
        Some(x) if x.size != size => Err(Error::Size {
            path: path.to_path_buf(),
            got: size,
            expected: x.size,
            why: x.why.clone(),
        }),
        _ => Ok(()),
    }
}

/// A scanned folder: its path and the indexed files in it.
struct Folder {
    dir: PathBuf,
    scan: Scan,
}

impl Folder {
    fn paths(&self) -> Vec<PathBuf> {
        paths_of(&self.dir, &self.scan)
    }
}

/// The scans of the data root's sets.
struct ProjectorScans {
    train: Folder,
    test: Folder,
    refs: Folder,
    sl: Folder,
}

impl ProjectorScans {
    fn get(&self, set: ProjectorSet) -> &Folder {
        match set {
            ProjectorSet::Train => &self.train,
            ProjectorSet::Test => &self.test,
            ProjectorSet::Ref => &self.refs,
            ProjectorSet::Sl => &self.sl,
        }
    }

    /// Images per set, each the contiguous run from `img_0001.png`.
    fn counts(&self) -> SetCounts {
        SetCounts {
            train: self.train.scan.contiguous(),
            test: self.test.scan.contiguous(),
            refs: self.refs.scan.contiguous(),
            sl: self.sl.scan.contiguous(),
        }
    }
}

/// The scans of the setup's capture sets (`cam/raw/*`).
struct CaptureScans {
    refs: Folder,
    train: Folder,
    test: Folder,
    sl: Folder,
}

impl CaptureScans {
    fn get(&self, set: CaptureSet) -> &Folder {
        match set {
            CaptureSet::Ref => &self.refs,
            CaptureSet::Train => &self.train,
            CaptureSet::Test => &self.test,
            CaptureSet::Sl => &self.sl,
        }
    }

    /// Every capture set, in the order of [`CaptureSet::ALL`].
    fn all(&self) -> [&Folder; 4] {
        [&self.refs, &self.train, &self.test, &self.sl]
    }

    /// Captures per set: the contiguous run from `img_0001.png`, except for the references,
    /// where every indexed file counts (only black, white and gray are required).
    fn counts(&self) -> SetCounts {
        SetCounts {
            train: self.train.scan.contiguous(),
            test: self.test.scan.contiguous(),
            refs: self.refs.scan.indices.len(),
            sl: self.sl.scan.contiguous(),
        }
    }
}

/// What the folders of the root and the setup hold, before any image is read.
struct Scans {
    prj: ProjectorScans,
    cap: CaptureScans,
    references: References,
    /// `cam/desire/test`, and its scan when the folder exists.
    desired_dir: PathBuf,
    desired: Option<Scan>,
    /// `cam/desire/train` (the closed-loop pairs' desired views) and its scan.
    loop_dir: PathBuf,
    loop_views: Scan,
    /// Model names under `prj/cmp/test` (sorted) and the scan of each one's folder.
    models: Vec<String>,
    model_scans: Vec<Folder>,
}

/// The image files of each pixel space.
struct SpacePaths {
    /// Network size: the root's train, test and ref images and the gray image x0.
    network: Vec<PathBuf>,
    /// The compensation images of each model (`prj/cmp/test/NAME`): any size, one per model
    /// (a linear rung writes them on its lattice, a CompenNet++ rung at the network size).
    models: Vec<Vec<PathBuf>>,
    /// Projector size: the structured-light patterns.
    projector: Vec<PathBuf>,
    /// Camera size: every capture set, then the desired images, then the closed-loop pairs'
    /// desired views.
    camera: Vec<PathBuf>,
    /// Whether the gray image x0 (`ROOT/ref/img_gray.png`) is present.
    gray_input: bool,
}

/// The size every image of each space must have; `None` when nothing sets it.
struct SpaceSizes {
    network: Option<Expect>,
    projector: Option<Expect>,
    camera: Option<Expect>,
}

pub(super) fn survey(setup: &Setup, decode: bool, cap: usize) -> Validation {
    let root = setup.root();
    let mut pr = Problems {
        kept: Vec::new(),
        total: 0,
        cap,
    };
    let scans = scan_all(setup, &mut pr);
    let paths = space_paths(root, &scans);
    let sizes = space_sizes(setup, &paths);
    let images_checked = check_files(&paths, &sizes, decode, &mut pr);

    // --- counts and cross-checks
    let projector_images = scans.prj.counts();
    let captures = scans.cap.counts();
    let captured_train = captures.train;
    check_pairing(root, &scans, &mut pr);
    check_network_sides(sizes.network.as_ref(), &mut pr);

    let size = |x: &Option<Expect>| x.as_ref().map(|x| x.size);
    Validation {
        info: SetupInfo {
            root: root.path().to_path_buf(),
            setup: setup.relative(),
            // The camera size is the black reference's size only; a stand-in used for checking
            // when it is unreadable is not reported as the camera size.
            camera_size: if scans.references.black {
                pngio::png_size(&setup.reference_path(Reference::Black)).ok()
            } else {
                None
            },
            network_size: size(&sizes.network),
            projector_size: size(&sizes.projector),
            projector_images,
            gray_input: paths.gray_input,
            captures,
            references: scans.references,
            desired_test: scans.desired.as_ref().map(Scan::contiguous),
            // Views past the last capture belong to pairs not captured yet.
            loop_pairs: (scans.loop_views.indices.iter().copied())
                .filter(|&i| i <= captured_train)
                .collect(),
            compensated: scans.models,
        },
        problems: pr.kept,
        total_problems: pr.total,
        images_checked,
    }
}

/// Scans: root sets, capture sets (the named references checked), desired, compensation models.
fn scan_all(setup: &Setup, pr: &mut Problems) -> Scans {
    let root = setup.root();
    let mut prj = |set: ProjectorSet| {
        let dir = root.dir(set);
        let scan = pr.scan(&dir, false);
        Folder { dir, scan }
    };
    // Fields are evaluated in the order written: the order of `ProjectorSet::ALL`.
    let prj = ProjectorScans {
        train: prj(ProjectorSet::Train),
        test: prj(ProjectorSet::Test),
        refs: prj(ProjectorSet::Ref),
        sl: prj(ProjectorSet::Sl),
    };
    let mut cap = |set: CaptureSet| {
        let dir = setup.capture_dir(set);
        let scan = pr.scan(&dir, set == CaptureSet::Ref);
        Folder { dir, scan }
    };
    // The order of `CaptureSet::ALL`.
    let cap = CaptureScans {
        refs: cap(CaptureSet::Ref),
        train: cap(CaptureSet::Train),
        test: cap(CaptureSet::Test),
        sl: cap(CaptureSet::Sl),
    };
    let references = check_references(&cap.refs, pr);

    let desired_dir = setup.desired_dir();
    let desired = desired_dir.is_dir().then(|| pr.scan(&desired_dir, false));
    let loop_dir = setup.loop_desired_dir();
    let loop_views = pr.scan(&loop_dir, true);

    let models = match setup.compensated_models() {
        Ok(m) => m,
        Err(e) => {
            pr.push(e);
            Vec::new()
        }
    };
    let model_scans: Vec<Folder> = models
        .iter()
        .map(|m| {
            let dir = setup.compensation_root().join(m);
            let scan = pr.scan(&dir, false);
            Folder { dir, scan }
        })
        .collect();
    Scans {
        prj,
        cap,
        references,
        desired_dir,
        desired,
        loop_dir,
        loop_views,
        models,
        model_scans,
    }
}

/// Which named references `cam/raw/ref` holds; each missing one is a problem.
fn check_references(refs: &Folder, pr: &mut Problems) -> References {
    let has = |r: Reference| refs.scan.indices.binary_search(&r.index()).is_ok();
    let references = References {
        black: has(Reference::Black),
        white: has(Reference::White),
        gray: has(Reference::Gray),
    };
    for r in Reference::ALL {
        if !has(r) {
            pr.push(Error::Missing {
                path: refs.dir.join(r.file_name()),
                expected: format!(
                    "{}; a setup needs black {}, white {} and gray {} in cam/raw/ref",
                    r.describe(),
                    Reference::Black.file_name(),
                    Reference::White.file_name(),
                    Reference::Gray.file_name()
                ),
            });
        }
    }
    references
}

/// The files of each space.
fn space_paths(root: &DataRoot, scans: &Scans) -> SpacePaths {
    let mut network = Vec::new();
    for set in [ProjectorSet::Train, ProjectorSet::Test, ProjectorSet::Ref] {
        network.extend(scans.prj.get(set).paths());
    }
    let gray_input = root.gray_input_path().is_file();
    if gray_input {
        network.push(root.gray_input_path());
    }
    let models = scans.model_scans.iter().map(Folder::paths).collect();
    let projector = scans.prj.get(ProjectorSet::Sl).paths();
    let mut camera = Vec::new();
    for f in scans.cap.all() {
        camera.extend(f.paths());
    }
    if let Some(s) = &scans.desired {
        camera.extend(paths_of(&scans.desired_dir, s));
    }
    camera.extend(paths_of(&scans.loop_dir, &scans.loop_views));
    SpacePaths {
        network,
        models,
        projector,
        camera,
        gray_input,
    }
}

/// The size of each space: the network size from the first training (else test) image, the
/// projector size from the first structured-light pattern, the camera size from the black
/// reference capture, each overruled by a clear majority of its space (see [`space_size`]).
fn space_sizes(setup: &Setup, paths: &SpacePaths) -> SpaceSizes {
    let root = setup.root();
    let train1 = root.image_path(ProjectorSet::Train, 1);
    let net_primary = if train1.is_file() {
        train1
    } else {
        root.image_path(ProjectorSet::Test, 1)
    };
    let net_why = format!("the network size, set by {}", net_primary.display());
    let network = space_size(Some((net_primary, net_why)), &paths.network, "network");
    let sl1 = root.image_path(ProjectorSet::Sl, 1);
    let prj_why = format!("the projector size, set by {}", sl1.display());
    let projector = space_size(Some((sl1, prj_why)), &paths.projector, "projector");
    let black = setup.reference_path(Reference::Black);
    let cam_why = format!(
        "the camera size, set by the black reference capture {}",
        black.display()
    );
    let camera = space_size(Some((black, cam_why)), &paths.camera, "camera");
    SpaceSizes {
        network,
        projector,
        camera,
    }
}

/// Reads every file, in report order: root sets, sl patterns, captures, desired, models.
/// Returns the number of files read.
fn check_files(paths: &SpacePaths, sizes: &SpaceSizes, decode: bool, pr: &mut Problems) -> usize {
    let mut jobs: Vec<(&Path, Option<&Expect>)> = Vec::new();
    jobs.extend(
        paths
            .network
            .iter()
            .map(|p| (p.as_path(), sizes.network.as_ref())),
    );
    jobs.extend(
        paths
            .projector
            .iter()
            .map(|p| (p.as_path(), sizes.projector.as_ref())),
    );
    jobs.extend(
        paths
            .camera
            .iter()
            .map(|p| (p.as_path(), sizes.camera.as_ref())),
    );
    // Each model's images have the size of its first (itself checked as an image).
    let firsts: Vec<Option<Expect>> = paths
        .models
        .iter()
        .map(|m| {
            let first = m.first()?;
            Some(Expect {
                size: pngio::png_size(first).ok()?,
                why: format!("the size of this model's first image, {}", first.display()),
            })
        })
        .collect();
    for (m, first) in paths.models.iter().zip(&firsts) {
        jobs.extend(
            m.iter()
                .enumerate()
                .map(|(k, p)| (p.as_path(), if k == 0 { None } else { first.as_ref() })),
        );
    }
    for r in par_map(&jobs, |(p, x)| check_file(p, *x, decode)) {
        if let Err(e) = r {
            pr.push(e);
        }
    }
    jobs.len()
}

/// Every capture (and desired image) needs the projector image it belongs to, and the
/// closed-loop pairs' desired views are the training set's last pairs, each with its view.
fn check_pairing(root: &DataRoot, scans: &Scans, pr: &mut Problems) {
    for set in [CaptureSet::Train, CaptureSet::Test, CaptureSet::Sl] {
        let f = scans.cap.get(set);
        let pset = set.projector_set();
        let prj_have = scans.prj.get(pset).scan.contiguous();
        unpaired(pr, &f.dir, &f.scan, &root.dir(pset), prj_have, "a capture");
    }
    if let Some(s) = &scans.desired {
        let prj_dir = root.dir(ProjectorSet::Test);
        let prj_have = scans.prj.test.scan.contiguous();
        unpaired(
            pr,
            &scans.desired_dir,
            s,
            &prj_dir,
            prj_have,
            "a desired image",
        );
    }
    let captured = scans.cap.get(CaptureSet::Train).scan.contiguous();
    if let Err(e) = check_loop_views(&scans.loop_dir, &scans.loop_views.indices, captured) {
        pr.push(e);
    }
}

/// A problem for the first image of `s` (in `dir`) beyond the `prj_have` projector images of
/// `prj_dir`.
fn unpaired(pr: &mut Problems, dir: &Path, s: &Scan, prj_dir: &Path, prj_have: usize, what: &str) {
    if let (Some(&i), Some(&last)) = (s.indices.iter().find(|&&i| i > prj_have), s.indices.last()) {
        pr.push(Error::Input(format!(
            "{}: {what} without a projector image: {} holds only {prj_have} images \
             (the set in {} runs to {})",
            dir.join(pngio::indexed_name(i)).display(),
            prj_dir.display(),
            dir.display(),
            pngio::indexed_name(last)
        )));
    }
}

/// The models halve the resolution twice: both network sides must be divisible by 4.
fn check_network_sides(network: Option<&Expect>, pr: &mut Problems) {
    if let Some(n) = network
        && (n.size.width % 4 != 0 || n.size.height % 4 != 0)
    {
        pr.push(Error::Input(format!(
            "network size {} ({}): both sides must be divisible by 4 (the models halve the \
             resolution twice)",
            n.size, n.why
        )));
    }
}
