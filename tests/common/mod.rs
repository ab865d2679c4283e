//! Helpers shared by the integration tests.

#![allow(dead_code)]

use std::path::Path;
use std::process::{Command, Output};

/// Runs the `compend` binary with `args` and returns its output.
pub fn compend(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_compend"))
        .args(args)
        .output()
        .expect("the compend binary runs")
}

/// Runs `compend` in `dir`.
pub fn compend_in(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_compend"))
        .current_dir(dir)
        .args(args)
        .output()
        .expect("the compend binary runs")
}

pub fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Asserts an exit code and shows stderr when it differs.
pub fn assert_code(o: &Output, code: i32) {
    assert_eq!(
        o.status.code(),
        Some(code),
        "exit code; stdout:\n{}\nstderr:\n{}",
        stdout(o),
        stderr(o)
    );
}
