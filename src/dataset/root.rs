//! The data root and its projector-side sets (docs/architecture.md, "Dataset layout"):
//! `ROOT/train`, `test` and `ref` at network size, `ROOT/sl` at projector size, and the gray
//! image x0 `ROOT/ref/img_gray.png`. Sizes are (width, height) in pixels of the space named.

use std::fs;
use std::path::{Path, PathBuf};

use super::load::{read_all, take_count};
use super::names::{absolute, check_index, count_dir};
use crate::error::{Error, Result};
use crate::pngio;
use crate::raster::{ImageSize, PrjImage};

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
    pub fn network_size(&self) -> Result<ImageSize> {
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
    pub fn projector_size(&self) -> Result<ImageSize> {
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

    /// Expected size of the images of a set, why (for error messages) and the file that sets it.
    fn expected_size(&self, set: ProjectorSet) -> Result<(ImageSize, String, PathBuf)> {
        Ok(match set {
            ProjectorSet::Sl => {
                let setter = self.image_path(ProjectorSet::Sl, 1);
                (
                    self.projector_size()?,
                    format!("the projector size, set by {}", setter.display()),
                    setter,
                )
            }
            _ => (
                self.network_size()?,
                self.network_why(),
                self.network_setter(),
            ),
        })
    }

    /// The file that sets the network size: `train/img_0001.png`, else `test/img_0001.png`.
    fn network_setter(&self) -> PathBuf {
        let train = self.image_path(ProjectorSet::Train, 1);
        if train.is_file() {
            train
        } else {
            self.image_path(ProjectorSet::Test, 1)
        }
    }

    fn network_why(&self) -> String {
        format!(
            "the network size, set by {}",
            self.network_setter().display()
        )
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
        let (size, why, setter) = self.expected_size(set)?;
        let paths: Vec<PathBuf> = (1..=n).map(|i| self.image_path(set, i)).collect();
        read_all(&paths, size, &why, &setter)
    }

    /// Image `index` (1-based) of a set, checked against the network size (the projector size
    /// for [`ProjectorSet::Sl`]).
    pub fn load_one(&self, set: ProjectorSet, index: usize) -> Result<PrjImage> {
        check_index(index)?;
        let (size, why, _) = self.expected_size(set)?;
        pngio::read_rgb_sized(&self.image_path(set, index), size, &why)
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

    /// [`DataRoot::write`], unless the file already holds `img` (as written: 8-bit values).
    /// Anything else there (another image, another size, an unreadable file, a folder) is an
    /// input error naming it: a root's captures were taken of its images, so writers that
    /// may meet a root already in use (`calibrate`, `patterns`, `sim export`) replace none.
    pub fn write_new(&self, set: ProjectorSet, index: usize, img: &PrjImage) -> Result<()> {
        check_index(index)?;
        if !holds(&self.image_path(set, index), img)? {
            self.write(set, index, img)?;
        }
        Ok(())
    }

    /// [`DataRoot::write_gray_input`] as [`DataRoot::write_new`] writes.
    pub fn write_new_gray_input(&self, img: &PrjImage) -> Result<()> {
        if !holds(&self.gray_input_path(), img)? {
            self.write_gray_input(img)?;
        }
        Ok(())
    }
}

/// Whether `path` holds `img` as [`pngio::write_rgb`] writes it; `false` when nothing is there,
/// an input error naming it when something else is.
fn holds(path: &Path, img: &PrjImage) -> Result<bool> {
    if fs::symlink_metadata(path).is_err() {
        return Ok(false);
    }
    let other = |what: String| {
        Error::Input(format!(
            "{}: {what}, not the image to be written there; the images of a data root are \
             never replaced (its captures were taken of them)",
            path.display()
        ))
    };
    let found: PrjImage = pngio::read_rgb(path).map_err(|e| other(format!("unreadable ({e})")))?;
    if found.size() != img.size() {
        return Err(other(format!("a {} image", found.size())));
    }
    let expected = pngio::quantize(img);
    let same = found
        .data()
        .iter()
        .zip(expected.data())
        .all(|(a, b)| (a - b).abs() <= 0.25 / 255.0);
    if !same {
        return Err(other("another image".into()));
    }
    Ok(true)
}

fn is_root(p: &Path) -> bool {
    p.join("train").is_dir() && p.join("test").is_dir()
}
