//! A setup and its capture sets (docs/architecture.md, "Dataset layout"): `cam/raw/{ref,train,
//! test,sl}` at camera size (the size of the black reference capture), reference captures by
//! name, desired images in `cam/desire/test`, compensation images under `prj/cmp/test/<model>`.
//! Sizes are (width, height) in pixels of the space named.

use std::fs;
use std::path::{Path, PathBuf};

use super::load::{blame_the_odd_one, read_all, read_all_with, take_count};
use super::names::{absolute, check_index, check_loop_views, check_plain_name, count_dir, scan};
use super::root::{DataRoot, ProjectorSet};
use crate::error::{Error, Result};
use crate::pngio;
use crate::raster::{CamImage, Camera, ImageSize, Levels, PrjImage};

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

/// Captures paired with the projector images they are captures of (same order, from index 1).
#[derive(Clone, Debug)]
pub struct Pairs {
    /// Captures x̃_i (camera size).
    pub captures: Vec<CamImage>,
    /// Projector images x_i (network size).
    pub inputs: Vec<PrjImage>,
}

/// `cam/unreachable.png` of the setup folder `setup` ([`Setup::unreachable_path`]), for a reader
/// that has the folder's path from a record and does not open the setup.
pub fn unreachable_path_of(setup: &Path) -> PathBuf {
    setup.join("cam").join("unreachable.png")
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

    /// `cam/unreachable.png`: where in the displayable area no model can compensate, and why
    /// ([`crate::fov::Reach::picture`]), as calibration found it.
    pub fn unreachable_path(&self) -> PathBuf {
        unreachable_path_of(&self.path)
    }

    /// `cam/desire/test`: desired viewer images z' in camera view.
    pub fn desired_dir(&self) -> PathBuf {
        self.path.join("cam").join("desire").join("test")
    }

    /// `cam/desire/train`: for each closed-loop training pair, the desired view (camera pixels)
    /// its projector image was compensated to give, under the pair's index. Sampling pairs have
    /// none, so the folder's numbering starts after them.
    pub fn loop_desired_dir(&self) -> PathBuf {
        loop_desired_dir(&self.path)
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
    pub fn camera_size(&self) -> Result<ImageSize> {
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

    /// The closed-loop pairs among the first `ntrain` training pairs: the indices (1-based,
    /// sorted) with a desired view in [`Setup::loop_desired_dir`]. They must be the training
    /// set's last pairs, each with its view: a view missing among them is an error naming the
    /// file. Views past the last capture (pairs not captured yet) are not pairs.
    pub fn loop_pairs(&self, ntrain: usize) -> Result<Vec<usize>> {
        let dir = self.loop_desired_dir();
        let mut found = super::names::scan_indices(&dir)?;
        if !found.is_empty() {
            let last = self.count(CaptureSet::Train)?;
            check_loop_views(&dir, &found, last)?;
            found.retain(|&i| i <= last);
        }
        found.retain(|&i| i <= ntrain);
        Ok(found)
    }

    /// Loads the desired views of the closed-loop training pairs `indices` at camera size.
    pub fn load_loop_desired(&self, indices: &[usize]) -> Result<Vec<CamImage>> {
        let dir = self.loop_desired_dir();
        let paths: Vec<PathBuf> = indices
            .iter()
            .map(|&i| dir.join(pngio::indexed_name(i)))
            .collect();
        read_all(
            &paths,
            self.camera_size()?,
            &self.camera_why(),
            &self.reference_path(Reference::Black),
        )
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
        let black = self.reference_path(Reference::Black);
        pngio::read_rgb_sized(&p, self.camera_size()?, &self.camera_why()).map_err(|e| match e {
            // The black reference sets the camera size; when it is the odd one out among the
            // references and the training captures, name it.
            Error::Size { got, .. } if p != black => {
                let mut group: Vec<PathBuf> = [Reference::White, Reference::Gray]
                    .into_iter()
                    .map(|r| self.reference_path(r))
                    .collect();
                let n = self.count(CaptureSet::Train).unwrap_or(0);
                group.extend((1..=n).map(|i| self.capture_path(CaptureSet::Train, i)));
                blame_the_odd_one(e, &group, got, &black)
            }
            e => e,
        })
    }

    /// Loads the first `n` captures of a set (all when `None`) at camera size. For
    /// [`CaptureSet::Ref`] use [`Setup::load_reference`].
    pub fn load_captures(&self, set: CaptureSet, n: Option<usize>) -> Result<Vec<CamImage>> {
        let size = self.camera_size()?;
        let why = self.camera_why();
        self.read_captures(set, n, |p| pngio::read_rgb_sized(p, size, &why))
    }

    /// [`Setup::load_captures`] as the levels the files store ([`Levels`]: a quarter of the
    /// memory of f32 values for 8-bit PNGs, the same values), for fits that hold many.
    pub fn load_capture_levels(
        &self,
        set: CaptureSet,
        n: Option<usize>,
    ) -> Result<Vec<Levels<Camera>>> {
        let size = self.camera_size()?;
        let why = self.camera_why();
        self.read_captures(set, n, |p| pngio::read_levels_sized(p, size, &why))
    }

    fn read_captures<T: Send>(
        &self,
        set: CaptureSet,
        n: Option<usize>,
        read: impl Fn(&Path) -> Result<T> + Sync + Send,
    ) -> Result<Vec<T>> {
        let dir = self.capture_dir(set);
        let n = take_count(&dir, count_dir(&dir)?, n, "captures")?;
        if n == 0 {
            return Ok(Vec::new());
        }
        let paths: Vec<PathBuf> = (1..=n).map(|i| self.capture_path(set, i)).collect();
        let images = read_all_with(&paths, &self.reference_path(Reference::Black), read).map_err(
            |e| match e {
                Error::Size { got, .. } => {
                    blame_the_odd_one(e, &paths, got, &self.reference_path(Reference::Black))
                }
                e => e,
            },
        )?;
        // Structured light needs only intensity.
        if set != CaptureSet::Sl {
            warn_if_grayscale(&dir, &paths);
        }
        Ok(images)
    }

    /// Loads the first `n` desired images of `cam/desire/test` (all when `None`) at camera size.
    pub fn load_desired(&self, n: Option<usize>) -> Result<Vec<CamImage>> {
        let dir = self.desired_dir();
        let n = take_count(&dir, count_dir(&dir)?, n, "desired images")?;
        if n == 0 {
            return Ok(Vec::new());
        }
        let paths: Vec<PathBuf> = (1..=n).map(|i| dir.join(pngio::indexed_name(i))).collect();
        read_all(
            &paths,
            self.camera_size()?,
            &self.camera_why(),
            &self.reference_path(Reference::Black),
        )
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
        let n = self.pair_count(set, n)?;
        Ok(Pairs {
            captures: self.load_captures(set, Some(n))?,
            inputs: self.root.load(set.projector_set(), Some(n))?,
        })
    }

    /// [`Setup::load_train`] with the captures as the levels the files store
    /// ([`Setup::load_capture_levels`]).
    pub fn load_train_levels(
        &self,
        n: Option<usize>,
    ) -> Result<(Vec<Levels<Camera>>, Vec<PrjImage>)> {
        let set = CaptureSet::Train;
        let n = self.pair_count(set, n)?;
        Ok((
            self.load_capture_levels(set, Some(n))?,
            self.root.load(set.projector_set(), Some(n))?,
        ))
    }

    /// Training pair `index` (1-based): the capture as the levels its file stores, of the
    /// camera's size, and the projector image shown, of the network size. For a fit that takes
    /// its pairs as they arrive ([`crate::fit::GrowingFit`]).
    pub fn load_train_pair(&self, index: usize) -> Result<(Levels<Camera>, PrjImage)> {
        check_index(index)?;
        let capture = pngio::read_levels_sized(
            &self.capture_path(CaptureSet::Train, index),
            self.camera_size()?,
            &self.camera_why(),
        )?;
        Ok((capture, self.root.load_one(ProjectorSet::Train, index)?))
    }

    /// How many pairs of `set` to load for `n`, refused when either folder is short.
    fn pair_count(&self, set: CaptureSet, n: Option<usize>) -> Result<usize> {
        let cap_dir = self.capture_dir(set);
        let n = take_count(&cap_dir, count_dir(&cap_dir)?, n, "captures")?;
        let prj_dir = self.root.dir(set.projector_set());
        take_count(&prj_dir, count_dir(&prj_dir)?, Some(n), "projector images")?;
        Ok(n)
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

    /// Writes the desired view of closed-loop training pair `index` (1-based) to
    /// `cam/desire/train`. Returns the path.
    pub fn write_loop_desired(&self, index: usize, img: &CamImage) -> Result<PathBuf> {
        check_index(index)?;
        let p = self.loop_desired_dir().join(pngio::indexed_name(index));
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
}

/// Captures read as gray (a grayscale PNG has the same value in R, G and B): a colour model
/// fitted on them cannot tell the projector's channels apart on the surface, so colour content
/// is compensated wrongly. Logged as a warning naming the folder, the count and the first file
/// (a capture whose header cannot be read was already refused by the read).
fn warn_if_grayscale(dir: &Path, paths: &[PathBuf]) {
    let gray: Vec<&PathBuf> =
        super::load::par_map(paths, |p| pngio::is_grayscale(p).unwrap_or(false))
            .into_iter()
            .zip(paths)
            .filter_map(|(g, p)| g.then_some(p))
            .collect();
    let Some(first) = gray.first() else {
        return;
    };
    tracing::warn!(
        "{}: {} of {} captures are grayscale (the first: {}); compend fits colour and reads them \
         as gray, so colour content will be compensated wrongly: capture in colour (RGB)",
        dir.display(),
        gray.len(),
        paths.len(),
        first.display()
    );
}

/// [`Setup::loop_desired_dir`] of the setup folder `setup`, which need not exist yet.
pub fn loop_desired_dir(setup: &Path) -> PathBuf {
    setup.join("cam").join("desire").join("train")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reference_indices_are_official() {
        assert_eq!(Reference::Black.file_name(), "img_0001.png");
        assert_eq!(Reference::White.file_name(), "img_0125.png");
        assert_eq!(Reference::Gray.file_name(), "img_0126.png");
    }
}
