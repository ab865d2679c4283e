//! Helpers shared by the integration tests.

#![allow(dead_code)]

use std::io::Read;
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// How long one command of a test may run before it is killed and the test fails: 600 s, or
/// `COMPEND_TEST_TIMEOUT_S`. A hang then names its command instead of eating CI's whole budget.
fn command_deadline() -> Duration {
    let s = std::env::var("COMPEND_TEST_TIMEOUT_S")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(600);
    Duration::from_secs(s)
}

/// Runs `cmd` to its end like `Command::output`, but kills it past the deadline and panics
/// with the command and what it printed so far.
pub fn output_within(cmd: &mut Command) -> Output {
    let deadline = command_deadline();
    let mut child = cmd
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("{cmd:?} does not start: {e}"));
    let drain = |mut r: Box<dyn Read + Send>| {
        std::thread::spawn(move || {
            let mut buf = Vec::new();
            let _ = r.read_to_end(&mut buf);
            buf
        })
    };
    let out = drain(Box::new(child.stdout.take().expect("piped stdout")));
    let err = drain(Box::new(child.stderr.take().expect("piped stderr")));
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().expect("the child can be waited for") {
            break status;
        }
        if start.elapsed() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            let err = err.join().unwrap_or_default();
            panic!(
                "{cmd:?} still ran after {} s and was killed; its stderr:\n{}",
                deadline.as_secs(),
                String::from_utf8_lossy(&err)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    Output {
        status,
        stdout: out.join().unwrap_or_default(),
        stderr: err.join().unwrap_or_default(),
    }
}

/// Runs the `compend` binary with `args` and returns its output.
pub fn compend(args: &[&str]) -> Output {
    output_within(Command::new(env!("CARGO_BIN_EXE_compend")).args(args))
}

/// `compend train --method linear` with its defaults on `setup` into `out`.
pub fn train_linear(setup: &Path, out: &Path) -> Output {
    compend(&[
        "train",
        "--setup",
        setup.to_str().expect("utf-8 path"),
        "--method",
        "linear",
        "--out",
        out.to_str().expect("utf-8 path"),
    ])
}

/// Runs `compend` in `dir`.
pub fn compend_in(dir: &Path, args: &[&str]) -> Output {
    output_within(
        Command::new(env!("CARGO_BIN_EXE_compend"))
            .current_dir(dir)
            .args(args),
    )
}

/// The latency trials a calibration record lists (`latency.trials`), in camera exposures.
pub fn latency_trials(record: &serde_json::Value) -> Vec<u64> {
    record["latency"]["trials"]
        .as_array()
        .unwrap_or_else(|| panic!("no latency.trials in {record}"))
        .iter()
        .map(|t| t.as_u64().unwrap())
        .collect()
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

/// The variable that turns a missing GPU adapter or Xvfb from a skip into a failure (CI sets it).
pub const REQUIRE_GPU: &str = "COMPEND_REQUIRE_GPU_ADAPTER";

fn gpu_required() -> bool {
    std::env::var(REQUIRE_GPU).is_ok_and(|v| !v.is_empty() && v != "0")
}

/// The largest absolute difference between two images of the same size and space.
pub fn max_abs<S: compend::raster::Space>(
    a: &compend::raster::Rgb<S>,
    b: &compend::raster::Rgb<S>,
) -> f32 {
    assert_eq!(a.size(), b.size());
    a.data()
        .iter()
        .zip(b.data())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// Skips a test with a printed reason, or fails it when `COMPEND_REQUIRE_GPU_ADAPTER=1`.
pub fn skip_or_fail(reason: &str) {
    if gpu_required() {
        panic!("{reason}, and {REQUIRE_GPU}=1 requires it");
    }
    eprintln!("skipping: {reason} (set {REQUIRE_GPU}=1 to make this a failure)");
}

/// The GPU context, or `None` after printing why the test is skipped (a panic instead when
/// `COMPEND_REQUIRE_GPU_ADAPTER=1`). An adapter that exists but fails to open is a failure.
/// One device serves every test of the binary: NVIDIA's Vulkan driver can hang when threads
/// create instances and devices at once (it did here on an H200 in two of four parallel runs;
/// gfx-rs/wgpu#10234 and kvark/blade#336 report crashes from the same races).
pub fn gpu() -> Option<&'static compend::gpu::GpuContext> {
    static CONTEXT: std::sync::OnceLock<Result<compend::gpu::GpuContext, String>> =
        std::sync::OnceLock::new();
    let opened = CONTEXT.get_or_init(|| match compend::gpu::GpuContext::new() {
        Ok(ctx) => {
            eprintln!("GPU adapter: {}", ctx.describe());
            Ok(ctx)
        }
        Err(e) if compend::gpu::is_no_adapter(&e) => Err(format!("no GPU adapter ({e})")),
        Err(e) => panic!("a GPU adapter that exists opens a device: {e}"),
    });
    match opened {
        Ok(ctx) => Some(ctx),
        Err(reason) => {
            skip_or_fail(reason);
            None
        }
    }
}
