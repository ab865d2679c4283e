//! Whole-setup check: scans every folder of the root and the setup, reads every image (header
//! only, or fully decoded) and checks its size against the size of its space, collecting every
//! problem instead of stopping at the first.

use std::path::{Path, PathBuf};

use super::{
    CaptureSet, ProjectorSet, Reference, References, Scan, SetCounts, Setup, SetupInfo,
    par_map, scan,
};
use crate::error::Error;
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
    size: (usize, usize),
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
        return Some(Expect {
            size,
            why: why.clone(),
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

pub(super) fn survey(setup: &Setup, decode: bool, cap: usize) -> Validation {
    let root = setup.root();
    let mut pr = Problems {
        kept: Vec::new(),
        total: 0,
        cap,
    };

    // --- scans: root sets, capture sets, desired, compensation models
    let prj: Vec<(ProjectorSet, PathBuf, Scan)> = ProjectorSet::ALL
        .iter()
        .map(|&set| {
            let dir = root.dir(set);
            let s = pr.scan(&dir, false);
            (set, dir, s)
        })
        .collect();
    let prj_of = |set: ProjectorSet| {
        prj.iter()
            .find(|(s, _, _)| *s == set)
            .map(|(_, d, s)| (d, s))
            .expect("every projector set was scanned")
    };
    let cap_scans: Vec<(CaptureSet, PathBuf, Scan)> = CaptureSet::ALL
        .iter()
        .map(|&set| {
            let dir = setup.capture_dir(set);
            let s = pr.scan(&dir, set == CaptureSet::Ref);
            (set, dir, s)
        })
        .collect();
    let cap_of = |set: CaptureSet| {
        cap_scans
            .iter()
            .find(|(s, _, _)| *s == set)
            .map(|(_, d, s)| (d, s))
            .expect("every capture set was scanned")
    };

    let (ref_dir, ref_scan) = cap_of(CaptureSet::Ref);
    let has = |r: Reference| ref_scan.indices.binary_search(&r.index()).is_ok();
    let references = References {
        black: has(Reference::Black),
        white: has(Reference::White),
        gray: has(Reference::Gray),
    };
    for r in Reference::ALL {
        if !has(r) {
            pr.push(Error::Missing {
                path: ref_dir.join(r.file_name()),
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

    let desired_dir = setup.desired_dir();
    let desired_scan = desired_dir.is_dir().then(|| pr.scan(&desired_dir, false));

    let models = match setup.compensated_models() {
        Ok(m) => m,
        Err(e) => {
            pr.push(e);
            Vec::new()
        }
    };
    let model_scans: Vec<(PathBuf, Scan)> = models
        .iter()
        .map(|m| {
            let dir = setup.compensation_root().join(m);
            let s = pr.scan(&dir, false);
            (dir, s)
        })
        .collect();

    // --- the files of each space
    let mut network_paths = Vec::new();
    for set in [ProjectorSet::Train, ProjectorSet::Test, ProjectorSet::Ref] {
        let (d, s) = prj_of(set);
        network_paths.extend(paths_of(d, s));
    }
    let gray_input = root.gray_input_path().is_file();
    if gray_input {
        network_paths.push(root.gray_input_path());
    }
    let model_paths: Vec<PathBuf> = model_scans
        .iter()
        .flat_map(|(d, s)| paths_of(d, s))
        .collect();
    network_paths.extend(model_paths.iter().cloned());
    let (sl_dir, sl_scan) = prj_of(ProjectorSet::Sl);
    let projector_paths = paths_of(sl_dir, sl_scan);
    let mut camera_paths = Vec::new();
    for (_, d, s) in &cap_scans {
        camera_paths.extend(paths_of(d, s));
    }
    if let Some(s) = &desired_scan {
        camera_paths.extend(paths_of(&desired_dir, s));
    }

    // --- the size of each space
    let train1 = root.image_path(ProjectorSet::Train, 1);
    let net_primary = if train1.is_file() {
        train1
    } else {
        root.image_path(ProjectorSet::Test, 1)
    };
    let net_why = format!("the network size, set by {}", net_primary.display());
    let network = space_size(Some((net_primary, net_why)), &network_paths, "network");
    let sl1 = root.image_path(ProjectorSet::Sl, 1);
    let prj_why = format!("the projector size, set by {}", sl1.display());
    let projector = space_size(Some((sl1, prj_why)), &projector_paths, "projector");
    let black = setup.reference_path(Reference::Black);
    let cam_why = format!(
        "the camera size, set by the black reference capture {}",
        black.display()
    );
    let camera = space_size(Some((black, cam_why)), &camera_paths, "camera");

    // --- read every file, in report order: root sets, sl patterns, captures, desired, models
    let n_root = network_paths.len() - model_paths.len();
    let mut jobs: Vec<(&Path, Option<&Expect>)> = Vec::new();
    jobs.extend(
        network_paths[..n_root]
            .iter()
            .map(|p| (p.as_path(), network.as_ref())),
    );
    jobs.extend(
        projector_paths
            .iter()
            .map(|p| (p.as_path(), projector.as_ref())),
    );
    jobs.extend(camera_paths.iter().map(|p| (p.as_path(), camera.as_ref())));
    jobs.extend(
        network_paths[n_root..]
            .iter()
            .map(|p| (p.as_path(), network.as_ref())),
    );
    let images_checked = jobs.len();
    for r in par_map(&jobs, |(p, x)| check_file(p, *x, decode)) {
        if let Err(e) = r {
            pr.push(e);
        }
    }

    // --- counts and cross-checks
    let count = |s: &Scan| s.contiguous();
    let projector_images = SetCounts {
        train: count(prj_of(ProjectorSet::Train).1),
        test: count(prj_of(ProjectorSet::Test).1),
        refs: count(prj_of(ProjectorSet::Ref).1),
        sl: count(prj_of(ProjectorSet::Sl).1),
    };
    let captures = SetCounts {
        train: count(cap_of(CaptureSet::Train).1),
        test: count(cap_of(CaptureSet::Test).1),
        refs: ref_scan.indices.len(),
        sl: count(cap_of(CaptureSet::Sl).1),
    };
    // Every capture (and desired image) needs the projector image it belongs to.
    let mut unpaired = |dir: &Path, s: &Scan, prj_dir: &Path, prj_have: usize, what: &str| {
        if let Some(&i) = s.indices.iter().find(|&&i| i > prj_have) {
            pr.push(Error::Input(format!(
                "{}: {what} without a projector image: {} holds only {prj_have} images \
                 (the set in {} runs to {})",
                dir.join(pngio::indexed_name(i)).display(),
                prj_dir.display(),
                dir.display(),
                pngio::indexed_name(*s.indices.last().expect("found one"))
            )));
        }
    };
    for set in [CaptureSet::Train, CaptureSet::Test, CaptureSet::Sl] {
        let (d, s) = cap_of(set);
        let pset = set.projector_set();
        let prj_have = count(prj_of(pset).1);
        unpaired(d, s, &root.dir(pset), prj_have, "a capture");
    }
    let desired_test = desired_scan.as_ref().map(count);
    if let Some(s) = &desired_scan {
        let prj_dir = root.dir(ProjectorSet::Test);
        unpaired(
            &desired_dir,
            s,
            &prj_dir,
            projector_images.test,
            "a desired image",
        );
    }
    if let Some(n) = &network
        && (n.size.0 % 4 != 0 || n.size.1 % 4 != 0)
    {
        pr.push(Error::Input(format!(
            "network size {}x{} ({}): both sides must be divisible by 4 (the models halve the \
             resolution twice)",
            n.size.0, n.size.1, n.why
        )));
    }

    let size = |x: &Option<Expect>| x.as_ref().map(|x| ImageSize::from(x.size));
    Validation {
        info: SetupInfo {
            root: root.path().to_path_buf(),
            setup: setup.relative(),
            // The camera size is the black reference's size only; a stand-in used for checking
            // when it is unreadable is not reported as the camera size.
            camera_size: if references.black {
                pngio::png_size(&setup.reference_path(Reference::Black))
                    .ok()
                    .map(ImageSize::from)
            } else {
                None
            },
            network_size: size(&network),
            projector_size: size(&projector),
            projector_images,
            gray_input,
            captures,
            references,
            desired_test,
            compensated: models,
        },
        problems: pr.kept,
        total_problems: pr.total,
        images_checked,
    }
}
