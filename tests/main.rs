//! The one integration-test binary: each module tests one area, through the library API or by
//! running the real `compend` binary.

mod common;
mod metrics;
mod rig;
