//! The dataset layout of the CompenNet++ benchmark (DESIGN.md section 3).
//!
//! A [`DataRoot`] holds the projector-side images shared by all setups:
//!
//! ```text
//! ROOT/train/  x_i, network size        ROOT/test/  y_i, network size
//! ROOT/ref/    img_0001..img_0125 colour cube + img_gray.png (the gray image x0), network size
//! ROOT/sl/     structured-light patterns, projector size
//! ```
//!
//! A [`Setup`] is a (possibly nested) folder under the root holding captures, all at one camera
//! size (the size of the black reference capture):
//!
//! ```text
//! SETUP/cam/raw/{ref,train,test,sl}/   captures          SETUP/cam/desire/test/  z'
//! SETUP/prj/cmp/test/<model>/          compensation images (network size)
//! ```
//!
//! All files are `img_%04d.png`, 1-based ([`pngio::indexed_name`]); a set is numbered from
//! `img_0001.png` without gaps. Reference captures are addressed by name ([`Reference`]), never
//! by position in a folder listing; black, white and gray are all a setup needs in `cam/raw/ref`.
//!
//! Every missing, undecodable or mis-sized file is an error naming the path and what was
//! expected. Sizes are (width, height) in pixels of the space named.

mod validate;

use std::fs;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::pngio;
use crate::raster::{CamImage, ImageSize, PrjImage, Rgb, Space};

pub use validate::Validation;

/// File name of the gray projector image x0 in `ROOT/ref`.
pub const GRAY_INPUT_NAME: &str = "img_gray.png";

/// A projector-side image set in the data root.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ProjectorSet {
    /// `ROOT/train`: sampling images x_i (network size).
    Train,
    /// `ROOT/test`: validation images y_i (network size).
    Test,
    /// `ROOT/ref`: the 5×5×5 colour cube (network size).
    Ref,
    /// `ROOT/sl`: structured-light patterns (projector size).
    Sl,
}

impl ProjectorSet {
    pub const ALL: [ProjectorSet; 4] = [Self::Train, Self::Test, Self::Ref, Self::Sl];

    /// Folder name under the data root.
    pub fn dir_name(self) -> &'static str {
        match self {
            Self::Train => "train",
            Self::Test => "test",
            Self::Ref => "ref",
            Self::Sl => "sl",
        }
    }
}

/// A capture set of a setup, `SETUP/cam/raw/<name>`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CaptureSet {
    /// Captures of `ROOT/ref` (at least black, white and the gray surface image).
    Ref,
    /// Captures x̃_i of `ROOT/train`.
    Train,
    /// Captures ỹ_i of `ROOT/test`.
    Test,
    /// Captures of the structured-light patterns `ROOT/sl`.
    Sl,
}

impl CaptureSet {
    pub const ALL: [CaptureSet; 4] = [Self::Ref, Self::Train, Self::Test, Self::Sl];

    /// Folder name under `cam/raw`.
    pub fn dir_name(self) -> &'static str {
        match self {
            Self::Ref => "ref",
            Self::Train => "train",
            Self::Test => "test",
            Self::Sl => "sl",
        }
    }

    /// The projector-side set these are captures of.
    pub fn projector_set(self) -> ProjectorSet {
        match self {
            Self::Ref => ProjectorSet::Ref,
            Self::Train => ProjectorSet::Train,
            Self::Test => ProjectorSet::Test,
            Self::Sl => ProjectorSet::Sl,
        }
    }
}

/// The reference captures a setup needs, addressed by name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Reference {
    /// `cam/raw/ref/img_0001.png`: the capture of a black projector image (cube level 0,0,0).
    Black,
    /// `cam/raw/ref/img_0125.png`: the capture of a white projector image (cube level 255³).
    White,
    /// `cam/raw/ref/img_0126.png`: the surface image s̃, the capture of the gray image x0.
    Gray,
}

impl Reference {
    pub const ALL: [Reference; 3] = [Self::Black, Self::White, Self::Gray];

    /// 1-based file index in `cam/raw/ref`.
    pub fn index(self) -> usize {
        match self {
            Self::Black => 1,
            Self::White => 125,
            Self::Gray => 126,
        }
    }

    /// File name in `cam/raw/ref`, e.g. `img_0126.png`.
    pub fn file_name(self) -> String {
        pngio::indexed_name(self.index())
    }

    /// What the capture shows, for messages.
    pub fn describe(self) -> &'static str {
        match self {
            Self::Black => "the black reference capture",
            Self::White => "the white reference capture",
            Self::Gray => "the gray surface image",
        }
    }
}

/// Image counts per set.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SetCounts {
    pub train: usize,
    pub test: usize,
    #[serde(rename = "ref")]
    pub refs: usize,
    pub sl: usize,
}

/// Which named reference captures are present.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct References {
    pub black: bool,
    pub white: bool,
    pub gray: bool,
}

/// Summary of a setup and its data root.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SetupInfo {
    /// The data root (absolute).
    pub root: PathBuf,
    /// The setup folder relative to the root (`.` when it is the root itself); absolute when the
    /// setup lies outside an explicitly named root.
    pub setup: PathBuf,
    /// Camera size: the size of the black reference capture (unknown when it is unreadable).
    pub camera_size: Option<ImageSize>,
    /// Network size: the size of `ROOT/train/img_0001.png` (else `ROOT/test/img_0001.png`).
    pub network_size: Option<ImageSize>,
    /// Projector size: the size of `ROOT/sl/img_0001.png` (unknown without patterns).
    pub projector_size: Option<ImageSize>,
    /// Projector images in the root: train and test (contiguous from 1), ref cube, sl patterns.
    pub projector_images: SetCounts,
    /// Whether `ROOT/ref/img_gray.png` (the gray image x0) is present.
    pub gray_input: bool,
    /// Captures in `cam/raw/*`. Train, test and sl count the contiguous run from `img_0001`;
    /// ref counts every indexed file (only black, white and gray are required).
    pub captures: SetCounts,
    /// Which named reference captures are present.
    pub references: References,
    /// Number of desired images in `cam/desire/test`; `None` when the folder does not exist.
    pub desired_test: Option<usize>,
    /// Model names under `prj/cmp/test/` (sorted).
    pub compensated: Vec<String>,
}

/// A data root: a folder holding `train/` and `test/` (and usually `ref/`, `sl/`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DataRoot {
    path: PathBuf,
}

impl DataRoot {
    /// Opens an explicitly named data root; it must hold `train/` and `test/`.
    pub fn open(path: &Path) -> Result<Self> {
        let path = absolute(path)?;
        if !path.is_dir() {
            return Err(Error::Input(format!(
                "{}: data root not found (expected a folder holding train/ and test/)",
                path.display()
            )));
        }
        let missing: Vec<String> = ["train", "test"]
            .into_iter()
            .filter(|d| !path.join(d).is_dir())
            .map(|d| format!("{d}/"))
            .collect();
        if !missing.is_empty() {
            return Err(Error::Input(format!(
                "{}: not a data root: it has no {} folder (a data root holds train/ and test/)",
                path.display(),
                missing.join(" or ")
            )));
        }
        Ok(Self { path })
    }

    /// Finds the data root of a setup: the nearest ancestor of `setup` (the setup folder itself
    /// included) that holds both `train/` and `test/`.
    pub fn discover(setup: &Path) -> Result<Self> {
        let abs = absolute(setup)?;
        abs.ancestors()
            .find(|p| is_root(p))
            .map(|p| Self {
                path: p.to_path_buf(),
            })
            .ok_or_else(|| {
                Error::Input(format!(
                    "no data root found for setup {}: none of its parent folders holds both \
                     train/ and test/ (name the data root with --data)",
                    setup.display()
                ))
            })
    }

    /// Creates a data root for writing (the folder with `train/` and `test/`) or opens an
    /// existing one.
    pub fn create(path: &Path) -> Result<Self> {
        let path = absolute(path)?;
        for d in ["train", "test"] {
            let dir = path.join(d);
            fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, "create folder", e))?;
        }
        Ok(Self { path })
    }

    /// The root folder (absolute).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Folder of a projector-side set.
    pub fn dir(&self, set: ProjectorSet) -> PathBuf {
        self.path.join(set.dir_name())
    }

    /// Path of image `index` (1-based) of a projector-side set.
    pub fn image_path(&self, set: ProjectorSet, index: usize) -> PathBuf {
        self.dir(set).join(pngio::indexed_name(index))
    }

    /// Path of the gray projector image x0, `ROOT/ref/img_gray.png`.
    pub fn gray_input_path(&self) -> PathBuf {
        self.dir(ProjectorSet::Ref).join(GRAY_INPUT_NAME)
    }

    /// Number of images of a set, contiguous from `img_0001.png` (0 when the folder is absent).
    /// A gap is an [`Error::Missing`] naming the first missing file.
    pub fn count(&self, set: ProjectorSet) -> Result<usize> {
        count_dir(&self.dir(set))
    }

    /// Network size: the size of `train/img_0001.png`, else of `test/img_0001.png`.
    pub fn network_size(&self) -> Result<(usize, usize)> {
        let train = self.image_path(ProjectorSet::Train, 1);
        let test = self.image_path(ProjectorSet::Test, 1);
        if train.is_file() {
            pngio::png_size(&train)
        } else if test.is_file() {
            pngio::png_size(&test)
        } else {
            Err(Error::Missing {
                path: train,
                expected: format!(
                    "the first projector image, which sets the network size (nor is there {})",
                    test.display()
                ),
            })
        }
    }

    /// Projector size: the size of the first structured-light pattern `sl/img_0001.png`.
    pub fn projector_size(&self) -> Result<(usize, usize)> {
        let p = self.image_path(ProjectorSet::Sl, 1);
        if !p.is_file() {
            return Err(Error::Missing {
                path: p,
                expected: "the first structured-light pattern, which sets the projector size"
                    .into(),
            });
        }
        pngio::png_size(&p)
    }

    /// Expected size of the images of a set and why (for error messages).
    fn expected_size(&self, set: ProjectorSet) -> Result<((usize, usize), String)> {
        Ok(match set {
            ProjectorSet::Sl => (
                self.projector_size()?,
                format!(
                    "the projector size, set by {}",
                    self.image_path(ProjectorSet::Sl, 1).display()
                ),
            ),
            _ => (self.network_size()?, self.network_why()),
        })
    }

    fn network_why(&self) -> String {
        let train = self.image_path(ProjectorSet::Train, 1);
        let from = if train.is_file() {
            train
        } else {
            self.image_path(ProjectorSet::Test, 1)
        };
        format!("the network size, set by {}", from.display())
    }

    /// Loads the first `n` images of a set (all when `None`), each checked against the network
    /// size (the projector size for [`ProjectorSet::Sl`]). Images are `Rgb<Projector>` because
    /// they are what the projector shows, stored at network size (placed on the canvas later).
    pub fn load(&self, set: ProjectorSet, n: Option<usize>) -> Result<Vec<PrjImage>> {
        let dir = self.dir(set);
        let n = take_count(&dir, count_dir(&dir)?, n, "projector images")?;
        if n == 0 {
            return Ok(Vec::new());
        }
        let (size, why) = self.expected_size(set)?;
        let paths: Vec<PathBuf> = (1..=n).map(|i| self.image_path(set, i)).collect();
        read_all(&paths, size, &why)
    }

    /// Loads the gray projector image x0 (`ref/img_gray.png`) at network size.
    pub fn load_gray_input(&self) -> Result<PrjImage> {
        let p = self.gray_input_path();
        if !p.is_file() {
            return Err(Error::Missing {
                path: p,
                expected: "the gray projector image x0".into(),
            });
        }
        pngio::read_rgb_sized(&p, self.network_size()?, &self.network_why())
    }

    /// Writes image `index` (1-based) of a projector-side set, creating folders. Returns the path.
    pub fn write(&self, set: ProjectorSet, index: usize, img: &PrjImage) -> Result<PathBuf> {
        check_index(index)?;
        let p = self.image_path(set, index);
        pngio::write_rgb(&p, img)?;
        Ok(p)
    }

    /// Writes the gray projector image x0 to `ref/img_gray.png`. Returns the path.
    pub fn write_gray_input(&self, img: &PrjImage) -> Result<PathBuf> {
        let p = self.gray_input_path();
        pngio::write_rgb(&p, img)?;
        Ok(p)
    }
}

/// Captures paired with the projector images they are captures of (same order, from index 1).
#[derive(Clone, Debug)]
pub struct Pairs {
    /// Captures x̃_i (camera size).
    pub captures: Vec<CamImage>,
    /// Projector images x_i (network size).
    pub inputs: Vec<PrjImage>,
}

/// A setup: a folder of captures under (usually) a data root.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Setup {
    root: DataRoot,
    path: PathBuf,
}

impl Setup {
    /// Opens a setup folder; the data root is `data` when given, else found by
    /// [`DataRoot::discover`]. Only the folder's existence is checked here; see
    /// [`Setup::info`] and [`Setup::validate`] for its contents.
    pub fn open(setup: &Path, data: Option<&Path>) -> Result<Self> {
        let path = absolute(setup)?;
        if !path.is_dir() {
            return Err(Error::Missing {
                path,
                expected: "the setup folder (holding cam/raw/...)".into(),
            });
        }
        let root = match data {
            Some(d) => DataRoot::open(d)?,
            None => DataRoot::discover(&path)?,
        };
        Ok(Self { root, path })
    }

    /// Creates (or opens) a setup folder `rel` under `root` for writing, with `cam/raw`.
    pub fn create(root: &DataRoot, rel: &Path) -> Result<Self> {
        if rel.is_absolute()
            || rel
                .components()
                .any(|c| !matches!(c, std::path::Component::Normal(_)))
        {
            return Err(Error::Input(format!(
                "{}: a setup path under the data root must be relative, without . or ..",
                rel.display()
            )));
        }
        let path = root.path().join(rel);
        let raw = path.join("cam").join("raw");
        fs::create_dir_all(&raw).map_err(|e| Error::io(&raw, "create folder", e))?;
        Ok(Self {
            root: root.clone(),
            path,
        })
    }

    pub fn root(&self) -> &DataRoot {
        &self.root
    }

    /// The setup folder (absolute).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The setup folder relative to the root (`.` for the root itself), or the absolute path when
    /// it lies outside the root.
    pub fn relative(&self) -> PathBuf {
        let rel = self
            .path
            .strip_prefix(self.root.path())
            .ok()
            .map(Path::to_path_buf)
            .or_else(|| {
                // Paths spelled differently (symlinks, `..`): compare canonical forms.
                let (p, r) = (
                    fs::canonicalize(&self.path).ok()?,
                    fs::canonicalize(self.root.path()).ok()?,
                );
                p.strip_prefix(&r).ok().map(Path::to_path_buf)
            });
        match rel {
            Some(r) if r.as_os_str().is_empty() => PathBuf::from("."),
            Some(r) => r,
            None => self.path.clone(),
        }
    }

    /// `cam/raw/<set>`.
    pub fn capture_dir(&self, set: CaptureSet) -> PathBuf {
        self.path.join("cam").join("raw").join(set.dir_name())
    }

    /// Path of capture `index` (1-based) of a set.
    pub fn capture_path(&self, set: CaptureSet, index: usize) -> PathBuf {
        self.capture_dir(set).join(pngio::indexed_name(index))
    }

    /// Path of a named reference capture.
    pub fn reference_path(&self, r: Reference) -> PathBuf {
        self.capture_path(CaptureSet::Ref, r.index())
    }

    /// `cam/desire/test`: desired viewer images z' in camera view.
    pub fn desired_dir(&self) -> PathBuf {
        self.path.join("cam").join("desire").join("test")
    }

    /// `prj/cmp/test`: one folder of compensation images per model.
    pub fn compensation_root(&self) -> PathBuf {
        self.path.join("prj").join("cmp").join("test")
    }

    /// `prj/cmp/test/<model>`; the model name must be a single plain folder name.
    pub fn compensation_dir(&self, model: &str) -> Result<PathBuf> {
        check_plain_name(model, "model name")?;
        Ok(self.compensation_root().join(model))
    }

    /// Model names with a folder under `prj/cmp/test` (sorted; empty when there is none).
    pub fn compensated_models(&self) -> Result<Vec<String>> {
        let dir = self.compensation_root();
        let mut names = Vec::new();
        let entries = match fs::read_dir(&dir) {
            Ok(e) => e,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(names),
            Err(e) => return Err(Error::io(&dir, "list folder", e)),
        };
        for entry in entries {
            let entry = entry.map_err(|e| Error::io(&dir, "list folder", e))?;
            if entry.path().is_dir() {
                names.push(entry.file_name().to_string_lossy().into_owned());
            }
        }
        names.sort();
        Ok(names)
    }

    /// Camera size: the size of the black reference capture.
    pub fn camera_size(&self) -> Result<(usize, usize)> {
        let p = self.reference_path(Reference::Black);
        if !p.is_file() {
            return Err(Error::Missing {
                path: p,
                expected: "the black reference capture, which sets the camera size".into(),
            });
        }
        pngio::png_size(&p)
    }

    fn camera_why(&self) -> String {
        format!(
            "the camera size, set by the black reference capture {}",
            self.reference_path(Reference::Black).display()
        )
    }

    /// Number of captures of a set, contiguous from `img_0001.png` (0 when the folder is
    /// absent; a gap is an error naming the first missing file). For [`CaptureSet::Ref`], where
    /// only black, white and gray are required, it is the number of indexed files present.
    pub fn count(&self, set: CaptureSet) -> Result<usize> {
        let dir = self.capture_dir(set);
        match set {
            CaptureSet::Ref => Ok(scan(&dir)?.indices.len()),
            _ => count_dir(&dir),
        }
    }

    /// Number of desired images in `cam/desire/test` (contiguous from 1; 0 when absent).
    pub fn count_desired(&self) -> Result<usize> {
        count_dir(&self.desired_dir())
    }

    /// Loads a named reference capture at camera size.
    pub fn load_reference(&self, r: Reference) -> Result<CamImage> {
        let p = self.reference_path(r);
        if !p.is_file() {
            return Err(Error::Missing {
                path: p,
                expected: r.describe().into(),
            });
        }
        pngio::read_rgb_sized(&p, self.camera_size()?, &self.camera_why())
    }

    /// Loads the first `n` captures of a set (all when `None`) at camera size. For
    /// [`CaptureSet::Ref`] use [`Setup::load_reference`].
    pub fn load_captures(&self, set: CaptureSet, n: Option<usize>) -> Result<Vec<CamImage>> {
        let dir = self.capture_dir(set);
        let n = take_count(&dir, count_dir(&dir)?, n, "captures")?;
        if n == 0 {
            return Ok(Vec::new());
        }
        let paths: Vec<PathBuf> = (1..=n).map(|i| self.capture_path(set, i)).collect();
        read_all(&paths, self.camera_size()?, &self.camera_why())
    }

    /// Loads the first `n` desired images of `cam/desire/test` (all when `None`) at camera size.
    pub fn load_desired(&self, n: Option<usize>) -> Result<Vec<CamImage>> {
        let dir = self.desired_dir();
        let n = take_count(&dir, count_dir(&dir)?, n, "desired images")?;
        if n == 0 {
            return Ok(Vec::new());
        }
        let paths: Vec<PathBuf> = (1..=n).map(|i| dir.join(pngio::indexed_name(i))).collect();
        read_all(&paths, self.camera_size()?, &self.camera_why())
    }

    /// Loads the first `n` training pairs (x̃_i, x_i), or all captured ones when `None`.
    /// Asking for more than exist is an [`Error::Input`] naming the folder that is short.
    pub fn load_train(&self, n: Option<usize>) -> Result<Pairs> {
        self.load_pairs(CaptureSet::Train, n)
    }

    /// Loads the first `n` test pairs (ỹ_i, y_i), or all captured ones when `None`.
    pub fn load_test(&self, n: Option<usize>) -> Result<Pairs> {
        self.load_pairs(CaptureSet::Test, n)
    }

    fn load_pairs(&self, set: CaptureSet, n: Option<usize>) -> Result<Pairs> {
        let cap_dir = self.capture_dir(set);
        let n = take_count(&cap_dir, count_dir(&cap_dir)?, n, "captures")?;
        let pset = set.projector_set();
        let prj_dir = self.root.dir(pset);
        take_count(&prj_dir, count_dir(&prj_dir)?, Some(n), "projector images")?;
        Ok(Pairs {
            captures: self.load_captures(set, Some(n))?,
            inputs: self.root.load(pset, Some(n))?,
        })
    }

    /// Writes capture `index` (1-based) of a set, creating folders. Returns the path.
    pub fn write_capture(&self, set: CaptureSet, index: usize, img: &CamImage) -> Result<PathBuf> {
        check_index(index)?;
        let p = self.capture_path(set, index);
        pngio::write_rgb(&p, img)?;
        Ok(p)
    }

    /// Writes a named reference capture. Returns the path.
    pub fn write_reference(&self, r: Reference, img: &CamImage) -> Result<PathBuf> {
        self.write_capture(CaptureSet::Ref, r.index(), img)
    }

    /// Writes desired image `index` (1-based) to `cam/desire/test`. Returns the path.
    pub fn write_desired(&self, index: usize, img: &CamImage) -> Result<PathBuf> {
        check_index(index)?;
        let p = self.desired_dir().join(pngio::indexed_name(index));
        pngio::write_rgb(&p, img)?;
        Ok(p)
    }

    /// Writes a compensation image (network size, what the projector is given) as
    /// `prj/cmp/test/<model>/<file_name>`; `file_name` is the input's file name (official
    /// convention). Returns the path.
    pub fn write_compensation(
        &self,
        model: &str,
        file_name: &str,
        img: &PrjImage,
    ) -> Result<PathBuf> {
        check_plain_name(file_name, "file name")?;
        let p = self.compensation_dir(model)?.join(file_name);
        pngio::write_rgb(&p, img)?;
        Ok(p)
    }

    /// Header-level summary: counts, sizes, references, models. Every file's header is read and
    /// size-checked; the first problem found is returned as the error. For a full check that
    /// decodes every image and reports every problem, use [`Setup::validate`].
    pub fn info(&self) -> Result<SetupInfo> {
        let mut v = validate::survey(self, false, 1);
        match v.problems.drain(..).next() {
            Some(e) => Err(e),
            None => Ok(v.info),
        }
    }

    /// Full check: every image of every set (root and setup) is decoded and size-checked.
    /// Returns the summary (as far as it could be worked out) with every problem found; at most
    /// `max_problems` are kept, [`Validation::total_problems`] counts them all.
    pub fn validate(&self, max_problems: usize) -> Validation {
        validate::survey(self, true, max_problems)
    }
}

// ---------------------------------------------------------------------------------------------
// helpers

fn absolute(p: &Path) -> Result<PathBuf> {
    std::path::absolute(p).map_err(|e| Error::io(p, "resolve path", e))
}

fn is_root(p: &Path) -> bool {
    p.join("train").is_dir() && p.join("test").is_dir()
}

fn check_index(index: usize) -> Result<()> {
    if index == 0 {
        return Err(Error::Input(
            "image indices are 1-based (img_0001.png is the first)".into(),
        ));
    }
    Ok(())
}

fn check_plain_name(name: &str, what: &str) -> Result<()> {
    let bad = name.is_empty()
        || name == "."
        || name == ".."
        || name.contains('/')
        || name.contains('\\')
        || name.contains('\0');
    if bad {
        return Err(Error::Input(format!(
            "{what} {name:?}: expected a plain name (no path separators, not . or ..)"
        )));
    }
    Ok(())
}

/// The 1-based index of an official file name `img_NNNN.png`, exactly as
/// [`pngio::indexed_name`] writes it (so `img_01.png` or `img_0000.png` are not indexed files).
pub fn parse_indexed_name(name: &str) -> Option<usize> {
    let digits = name.strip_prefix("img_")?.strip_suffix(".png")?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let i: usize = digits.parse().ok()?;
    (i >= 1 && pngio::indexed_name(i) == name).then_some(i)
}

/// The indexed files of a folder.
#[derive(Clone, Debug, Default)]
pub(crate) struct Scan {
    /// Sorted 1-based indices of the `img_NNNN.png` files present.
    pub indices: Vec<usize>,
}

impl Scan {
    /// Length of the run 1, 2, … n of present indices.
    pub fn contiguous(&self) -> usize {
        self.indices
            .iter()
            .enumerate()
            .take_while(|(k, i)| **i == k + 1)
            .count()
    }

    /// The gap error, when some index lies beyond the contiguous run.
    pub fn gap(&self, dir: &Path) -> Option<Error> {
        let n = self.contiguous();
        let later = *self.indices.get(n)?;
        Some(Error::Missing {
            path: dir.join(pngio::indexed_name(n + 1)),
            expected: format!(
                "the set must be numbered from img_0001.png without gaps; {} exists",
                pngio::indexed_name(later)
            ),
        })
    }
}

/// Lists the indexed files of `dir`; an absent folder is empty.
pub(crate) fn scan(dir: &Path) -> Result<Scan> {
    let entries = match fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Scan::default()),
        Err(e) => return Err(Error::io(dir, "list folder", e)),
    };
    let mut indices = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| Error::io(dir, "list folder", e))?;
        if let Some(i) = entry.file_name().to_str().and_then(parse_indexed_name) {
            indices.push(i);
        }
    }
    indices.sort_unstable();
    Ok(Scan { indices })
}

/// Images in `dir`, contiguous from 1; a gap is an error naming the first missing file.
fn count_dir(dir: &Path) -> Result<usize> {
    let s = scan(dir)?;
    match s.gap(dir) {
        Some(e) => Err(e),
        None => Ok(s.contiguous()),
    }
}

/// Resolves a requested count against what `dir` holds.
fn take_count(dir: &Path, have: usize, want: Option<usize>, what: &str) -> Result<usize> {
    match want {
        None => Ok(have),
        Some(n) if n <= have => Ok(n),
        Some(n) => Err(Error::Input(format!(
            "{}: holds {have} {what}{}, but {n} were requested",
            dir.display(),
            if have > 0 {
                format!(
                    " ({}..{})",
                    pngio::indexed_name(1),
                    pngio::indexed_name(have)
                )
            } else {
                String::new()
            }
        ))),
    }
}

/// Maps `f` over `items` in parallel (rayon), keeping the order.
pub(crate) fn par_map<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync + Send) -> Vec<R> {
    use rayon::prelude::*;
    items.par_iter().map(f).collect()
}

/// Reads images in parallel, each checked against `size`; the first error in path order wins.
fn read_all<S: Space>(paths: &[PathBuf], size: (usize, usize), why: &str) -> Result<Vec<Rgb<S>>> {
    par_map(paths, |p| {
        if !p.is_file() {
            return Err(Error::Missing {
                path: p.clone(),
                expected: "an image of the set".into(),
            });
        }
        pngio::read_rgb_sized::<S>(p, size, why)
    })
    .into_iter()
    .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn indexed_names_round_trip_and_reject_others() {
        for i in [1, 42, 125, 126, 9999, 10000] {
            assert_eq!(parse_indexed_name(&pngio::indexed_name(i)), Some(i));
        }
        for bad in [
            "img_0000.png",
            "img_01.png",
            "img_00001.png",
            "img_gray.png",
            "img_0001.PNG",
            "img_0001.png.tmp",
            "x_0001.png",
            "img_+001.png",
        ] {
            assert_eq!(parse_indexed_name(bad), None, "{bad}");
        }
    }

    #[test]
    fn scan_counts_contiguous_run_and_names_first_gap() {
        let s = Scan {
            indices: vec![1, 2, 3, 5, 9],
        };
        assert_eq!(s.contiguous(), 3);
        let e = s.gap(Path::new("/d")).expect("a gap");
        let msg = e.to_string();
        assert!(msg.contains("/d/img_0004.png"), "{msg}");
        assert!(msg.contains("img_0005.png exists"), "{msg}");
        let s = Scan {
            indices: vec![2, 3],
        };
        assert_eq!(s.contiguous(), 0);
        assert!(
            s.gap(Path::new("/d"))
                .unwrap()
                .to_string()
                .contains("img_0001.png")
        );
        assert!(
            Scan {
                indices: vec![1, 2]
            }
            .gap(Path::new("/d"))
            .is_none()
        );
    }

    #[test]
    fn reference_indices_are_official() {
        assert_eq!(Reference::Black.file_name(), "img_0001.png");
        assert_eq!(Reference::White.file_name(), "img_0125.png");
        assert_eq!(Reference::Gray.file_name(), "img_0126.png");
    }

    #[test]
    fn plain_names_only() {
        assert!(check_plain_name("compennet++", "m").is_ok());
        for bad in ["", ".", "..", "a/b", "a\\b"] {
            assert!(check_plain_name(bad, "m").is_err(), "{bad}");
        }
    }
}
