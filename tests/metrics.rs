//! Metrics against an independent implementation.
//!
//! The fixtures in tests/fixtures/metrics were written by `tests/reference/metrics_ref.py make`
//! (seeded NumPy), and the expected numbers below were printed by
//! `python3 tests/reference/metrics_ref.py score A B` — NumPy 2.4 / SciPy 1.17, float64, filtering
//! with scipy.ndimage.correlate1d(mode="nearest"); no code shared with compend.

use std::path::{Path, PathBuf};

use compend::metrics::{self, Scores};
use compend::pngio;
use compend::raster::{Rgb, Unspecified};

use crate::common::{assert_code, compend, stderr, stdout};

fn fixture(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/metrics")
        .join(rel)
}

fn json_scores(args: &[&str]) -> Scores {
    let out = compend(args);
    assert_code(&out, 0);
    serde_json::from_str(stdout(&out).trim()).expect("metrics --json prints one JSON object")
}

fn close(got: Scores, psnr: f64, rmse: f64, ssim: f64, n: usize) {
    // The task's acceptance tolerances are 0.01 dB and 0.002 SSIM; we hold much tighter ones since
    // both sides compute in float64 from the same 8-bit values.
    assert!(
        (got.psnr - psnr).abs() < 1e-4,
        "psnr {} vs reference {psnr}",
        got.psnr
    );
    assert!(
        (got.rmse - rmse).abs() < 1e-6,
        "rmse {} vs reference {rmse}",
        got.rmse
    );
    assert!(
        (got.ssim - ssim).abs() < 1e-5,
        "ssim {} vs reference {ssim}",
        got.ssim
    );
    assert_eq!(got.n, n);
}

#[test]
fn folder_pair_matches_reference() {
    let (a, b) = (fixture("a"), fixture("b"));
    let s = json_scores(&[
        "metrics",
        a.to_str().unwrap(),
        b.to_str().unwrap(),
        "--json",
    ]);
    close(
        s,
        14.804658201400414,
        0.31501244917821086,
        0.6993628632634007,
        3,
    );
}

#[test]
fn single_pairs_match_reference() {
    let cases = [
        (
            "a/img_0001.png",
            "b/img_0001.png",
            16.97686912006503,
            0.24531108387900993,
            0.7447399303355547,
        ),
        (
            "a/img_0003.png",
            "b/img_0003.png",
            13.028639930232508,
            0.386481429516036,
            0.6628643433734229,
        ),
        // Unrelated images: SSIM near zero exercises the variance terms.
        (
            "a/img_0002.png",
            "a/img_0003.png",
            7.688659968067651,
            0.7147063306345367,
            0.009083975614875846,
        ),
    ];
    for (a, b, psnr, rmse, ssim) in cases {
        let (a, b) = (fixture(a), fixture(b));
        let s = json_scores(&[
            "metrics",
            a.to_str().unwrap(),
            b.to_str().unwrap(),
            "--json",
        ]);
        close(s, psnr, rmse, ssim, 1);
    }
}

#[test]
fn pooled_psnr_is_not_the_mean_of_per_image_psnr() {
    // PSNR of the pooled MSE differs from averaging per-image PSNRs whenever errors differ between
    // images; check the library pools.
    let load = |p: &str| pngio::read_rgb::<Unspecified>(&fixture(p)).unwrap();
    let pairs: Vec<(Rgb<Unspecified>, Rgb<Unspecified>)> = (1..=3)
        .map(|i| {
            (
                load(&format!("a/img_000{i}.png")),
                load(&format!("b/img_000{i}.png")),
            )
        })
        .collect();
    let pooled = metrics::score_pairs(pairs.iter().map(|(a, b)| (a, b))).unwrap();
    let mses: Vec<f64> = pairs
        .iter()
        .map(|(a, b)| metrics::mse(a, b).unwrap())
        .collect();
    let mean_mse = mses.iter().sum::<f64>() / 3.0;
    assert!((pooled.psnr - metrics::psnr_from_mse(mean_mse)).abs() < 1e-9);
    let mean_psnr = mses.iter().map(|&m| metrics::psnr_from_mse(m)).sum::<f64>() / 3.0;
    assert!(
        (pooled.psnr - mean_psnr).abs() > 0.1,
        "fixtures should have unequal errors"
    );
}

#[test]
fn ssim_properties() {
    let a = Rgb::<Unspecified>::from_fn(32, 24, |x, y| {
        [x as f32 / 31.0, y as f32 / 23.0, ((x * y) % 7) as f32 / 6.0]
    });
    assert!((metrics::ssim(&a, &a).unwrap() - 1.0).abs() < 1e-9);
    let b = a.map(|v| 0.5 * v + 0.2);
    let ab = metrics::ssim(&a, &b).unwrap();
    let ba = metrics::ssim(&b, &a).unwrap();
    assert!((ab - ba).abs() < 1e-12, "SSIM is symmetric");
    assert!(ab < 0.999 && ab > 0.0);
    // Identical images: infinite PSNR, zero RMSE.
    let s = metrics::score_pairs([(&a, &a)]).unwrap();
    assert!(s.psnr.is_infinite() && s.rmse == 0.0);
    // Different sizes are rejected.
    let c = Rgb::<Unspecified>::new(31, 24);
    assert!(metrics::ssim(&a, &c).is_err());
}

#[test]
fn table_output_is_readable() {
    let (a, b) = (fixture("a/img_0001.png"), fixture("b/img_0001.png"));
    let out = compend(&["metrics", a.to_str().unwrap(), b.to_str().unwrap()]);
    assert_code(&out, 0);
    let text = stdout(&out);
    assert!(text.contains("PSNR  16.9769 dB"), "{text}");
    assert!(text.contains("SSIM  0.744740"), "{text}");
}

#[test]
fn bad_inputs_exit_2_and_name_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let a = fixture("a/img_0001.png");
    let a = a.to_str().unwrap();

    // Corrupt PNG.
    let bad = dir.path().join("corrupt.png");
    std::fs::write(&bad, b"\x89PNG\r\n\x1a\nnot really").unwrap();
    let out = compend(&["metrics", a, bad.to_str().unwrap()]);
    assert_code(&out, 2);
    assert!(stderr(&out).contains("corrupt.png"), "{}", stderr(&out));

    // Missing file.
    let missing = dir.path().join("nope.png");
    let out = compend(&["metrics", a, missing.to_str().unwrap()]);
    assert_code(&out, 2);
    assert!(stderr(&out).contains("nope.png"), "{}", stderr(&out));

    // Size mismatch names both sizes.
    let small = dir.path().join("small.png");
    pngio::write_rgb(&small, &Rgb::<Unspecified>::new(8, 8)).unwrap();
    let out = compend(&["metrics", a, small.to_str().unwrap()]);
    assert_code(&out, 2);
    let err = stderr(&out);
    assert!(
        err.contains("small.png") && err.contains("8x8") && err.contains("48x40"),
        "{err}"
    );

    // A folder with a PNG that has no counterpart.
    let fa = dir.path().join("fa");
    let fb = dir.path().join("fb");
    std::fs::create_dir_all(&fa).unwrap();
    std::fs::create_dir_all(&fb).unwrap();
    std::fs::copy(a, fa.join("img_0001.png")).unwrap();
    let out = compend(&["metrics", fa.to_str().unwrap(), fb.to_str().unwrap()]);
    assert_code(&out, 2);
    assert!(stderr(&out).contains("img_0001.png"), "{}", stderr(&out));

    // A file and a folder.
    let out = compend(&["metrics", a, fb.to_str().unwrap()]);
    assert_code(&out, 2);

    // Usage error from clap.
    let out = compend(&["metrics", a]);
    assert_code(&out, 2);
}

#[test]
fn sharpness_falls_as_an_image_blurs_and_clipping_counts_the_ends() {
    use compend::raster::CamImage;
    let sharp = CamImage::from_fn(40, 30, |x, y| {
        let v = if (x / 4 + y / 4) % 2 == 0 { 0.8 } else { 0.2 };
        [v; 3]
    });
    // A 3×3 box blur of it, then another.
    let blur = |img: &CamImage| {
        CamImage::from_fn(40, 30, |x, y| {
            let mut s = 0.0;
            let mut n = 0.0;
            for dy in -1i32..=1 {
                for dx in -1i32..=1 {
                    let (xx, yy) = (x as i32 + dx, y as i32 + dy);
                    if (0..40).contains(&xx) && (0..30).contains(&yy) {
                        s += img.get(xx as usize, yy as usize)[0];
                        n += 1.0;
                    }
                }
            }
            [s / n; 3]
        })
    };
    let once = blur(&sharp);
    let twice = blur(&once);
    let (a, b, c) = (
        compend::metrics::sharpness(&sharp),
        compend::metrics::sharpness(&once),
        compend::metrics::sharpness(&twice),
    );
    assert!(a > b && b > c && c > 0.0, "{a} {b} {c}");
    assert_eq!(
        compend::metrics::sharpness(&CamImage::filled(40, 30, [0.5; 3])),
        0.0
    );
    // A quarter white, a quarter black, the rest in between.
    let img = CamImage::from_fn(4, 4, |x, _| match x {
        0 => [1.0, 0.3, 0.3],
        1 => [0.0; 3],
        _ => [0.5; 3],
    });
    assert_eq!(compend::metrics::clipping(&img), (0.25, 0.25));
}

/// The error over the pixels a mask holds (a projector's part of a set's picture, in
/// monitoring): the whole image's with a full mask, the hand-computed mean over the masked
/// pixels otherwise, none for an empty mask, and a mask of another size is refused.
#[test]
fn masked_mse_counts_only_the_masked_pixels() {
    let a: Rgb<Unspecified> = Rgb::from_fn(2, 2, |x, y| [0.1 * (x + 2 * y) as f32; 3]);
    let b: Rgb<Unspecified> = Rgb::from_fn(2, 2, |_, _| [0.0; 3]);
    let all = metrics::masked_mse(&a, &b, &[true; 4]).unwrap().unwrap();
    assert!((all - metrics::mse(&a, &b).unwrap()).abs() < 1e-12);
    // Pixels (1, 0) and (1, 1): 0.1 and 0.3 in every channel.
    let right = metrics::masked_mse(&a, &b, &[false, true, false, true])
        .unwrap()
        .unwrap();
    let want = (0.1f64 * 0.1 + 0.3 * 0.3) / 2.0;
    assert!((right - want).abs() < 1e-7, "{right} against {want}");
    assert_eq!(metrics::masked_mse(&a, &b, &[false; 4]).unwrap(), None);
    assert!(metrics::masked_mse(&a, &b, &[true; 3]).is_err());
}
