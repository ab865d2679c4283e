//! The dataset layout of the CompenNet++ benchmark (docs/architecture.md, "Dataset layout").
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
//! All files are `img_%04d.png`, 1-based ([`crate::pngio::indexed_name`]); a set is numbered
//! from `img_0001.png` without gaps. Reference captures are addressed by name ([`Reference`]),
//! never by position in a folder listing; black, white and gray are all a setup needs in
//! `cam/raw/ref`.
//!
//! Every missing, undecodable or mis-sized file is an error naming the path and what was
//! expected. Sizes are (width, height) in pixels of the space named.
//!
//! Files by job: `root.rs` the data root and its projector-side sets; `setup.rs` a setup, its
//! capture sets and named references; `info.rs` the setup summary; `validate.rs` the
//! whole-setup check behind [`Setup::info`] and [`Setup::validate`]; `names.rs` official file
//! names and folder scans; `load.rs` counting and reading with size checks.

mod info;
mod load;
pub mod manifest;
mod names;
mod root;
mod setup;
mod validate;

pub use info::{References, SetCounts, SetupInfo};
pub use names::{parse_indexed_name, scan_indices};
pub use root::{DataRoot, GRAY_INPUT_NAME, ProjectorSet};
pub use setup::{CaptureSet, Pairs, Reference, Setup, loop_desired_dir, unreachable_path_of};
pub use validate::Validation;
