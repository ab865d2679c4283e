//! Unit tests of the simulator's taps, blurs, adjoints and noise.

use super::bounce::Bounce;
use super::kernels::{approx_normal, blur_rgb, gaussian_kernel, mix64};
use super::pixel::tap;
use super::*;
use crate::raster::ImageSize;

#[test]
fn taps_read_zeros_outside_and_sum_to_one_inside() {
    let t = tap(2.25, 1.5, 5, 4);
    assert_eq!(t.base, 5 + 2);
    assert!((t.w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
    // Half a pixel left of the first column: half the weight is lost to the outside.
    let t = tap(-0.5, 0.0, 5, 4);
    assert_eq!(t.base, 0);
    assert!((t.w.iter().sum::<f32>() - 0.5).abs() < 1e-6);
    assert!((t.w[0] - 0.5).abs() < 1e-6);
    // Half a pixel past the last row and column.
    let t = tap(4.5, 3.5, 5, 4);
    assert_eq!(t.base as usize, 2 * 5 + 3);
    assert!((t.w[3] - 0.25).abs() < 1e-6 && t.w[0] == 0.0);
    // Exactly on the last pixel centre.
    let t = tap(4.0, 3.0, 5, 4);
    assert!((t.w[3] - 1.0).abs() < 1e-6);
}

#[test]
fn blur_is_self_adjoint_and_bounce_adjoint_matches() {
    let (w, h) = (13, 9);
    let a: Vec<f32> = (0..w * h * 3)
        .map(|i| ((i * 37 % 101) as f32) / 101.0)
        .collect();
    let b: Vec<f32> = (0..w * h * 3)
        .map(|i| ((i * 53 % 97) as f32) / 97.0)
        .collect();
    let k = gaussian_kernel(1.7);
    let lhs = dot(&blur_rgb(&a, w, h, &k), &b);
    let rhs = dot(&a, &blur_rgb(&b, w, h, &k));
    assert!((lhs - rhs).abs() < 1e-4 * lhs.abs(), "{lhs} {rhs}");

    let (w, h) = (170, 45);
    let bounce = Bounce::new(w, h, 0.3, 0.1);
    assert!(bounce.block >= 2, "exercise partial blocks");
    let a: Vec<f32> = (0..w * h * 3)
        .map(|i| ((i * 37 % 101) as f32) / 101.0)
        .collect();
    let b: Vec<f32> = (0..w * h * 3)
        .map(|i| ((i * 53 % 97) as f32) / 97.0)
        .collect();
    let lhs = dot(&bounce.forward(&a), &b);
    let rhs = dot(&a, &bounce.adjoint(&b));
    assert!((lhs - rhs).abs() < 1e-4 * lhs.abs(), "{lhs} {rhs}");
}

#[test]
fn sensor_adjoint_matches_forward() {
    // Every linear stage at once: defocus, specular, inter-reflection, colour mixing.
    let mut scene = crate::rig::builtin("specular-corner")
        .expect("built-in")
        .with_resolution(ImageSize::new(90, 50), ImageSize::new(70, 52));
    scene.projector.defocus_px = 1.3;
    scene.camera.blur_px = 0.8;
    // A white segment: at the drives themselves its Jacobian reproduces the map.
    scene.projector.white_boost = 0.8;
    // 30 and 15 mm are 1.4 and 0.7 of these camera pixels; blue does not spread.
    scene.subsurface = Some(crate::rig::scene::Subsurface {
        share: 0.7,
        radius_mm: [30.0, 15.0, 0.0],
    });
    let sim = Simulator::new(&scene, 3, Phase::Calibration).expect("builds");
    let ImageSize {
        width: pw,
        height: ph,
    } = sim.projector_size();
    let ImageSize {
        width: cw,
        height: ch,
    } = sim.camera_size();
    let a: Vec<f32> = (0..pw * ph * 3)
        .map(|i| ((i * 37 % 101) as f32) / 101.0)
        .collect();
    let b: Vec<f32> = (0..cw * ch * 3)
        .map(|i| ((i * 53 % 97) as f32) / 97.0)
        .collect();
    let fwd = sim.sensor(&sim.drive_to_emission(&a, false));
    let adj = sim.emission_to_drive_adjoint(&a, &sim.sensor_adjoint(&b));
    let (lhs, rhs) = (dot(&fwd, &b), dot(&a, &adj));
    assert!(lhs > 1.0, "the scene is lit: {lhs}");
    assert!((lhs - rhs).abs() < 1e-4 * lhs, "{lhs} vs {rhs}");
    // The camera's blur is in the forward model: without it the signal differs, and its total
    // (light is only moved, not lost, away from the frame's edge) nearly does not.
    scene.camera.blur_px = 0.0;
    let sharp = Simulator::new(&scene, 3, Phase::Calibration).expect("builds");
    let fwd_sharp = sharp.sensor(&sharp.drive_to_emission(&a, false));
    let moved: f64 = fwd
        .iter()
        .zip(&fwd_sharp)
        .map(|(p, q)| (p - q).abs() as f64)
        .sum();
    let (total, total_sharp) = (
        fwd.iter().map(|&v| v as f64).sum::<f64>(),
        fwd_sharp.iter().map(|&v| v as f64).sum::<f64>(),
    );
    assert!(moved > 1e-3 * total, "the blur moved {moved} of {total}");
    assert!(
        (total - total_sharp).abs() < 0.05 * total,
        "{total} vs {total_sharp}"
    );
}

#[test]
fn the_white_segment_brightens_greys_and_its_adjoint_matches() {
    let mut scene = crate::rig::builtin("white-plane")
        .expect("built-in")
        .with_resolution(ImageSize::new(40, 30), ImageSize::new(32, 24));
    scene.projector.white_boost = 1.0;
    let sim = Simulator::new(&scene, 1, Phase::Calibration).expect("builds");
    let one = |d: [f32; 3]| sim.drive_to_emission(&d, false);
    // White is twice what its primaries add up to; a primary alone gets nothing extra.
    let white = one([1.0, 1.0, 1.0]);
    let sum: Vec<f32> = (0..3)
        .map(|c| {
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
                .iter()
                .map(|d| one(*d)[c])
                .sum()
        })
        .collect();
    for c in 0..3 {
        assert!(
            (white[c] - 2.0 * sum[c]).abs() < 1e-5,
            "{white:?} vs {sum:?}"
        );
    }
    // The adjoint is that of the Jacobian: against a finite difference in a direction v at
    // drives whose channels differ.
    let (lhs, rhs) = jacobian_against_its_adjoint(&sim, 32 * 24 * 3);
    assert!(
        (lhs - rhs).abs() < 2e-3 * lhs.abs().max(1.0),
        "{lhs} vs {rhs}"
    );
}

/// ⟨J v, g⟩ by a central difference of [`Simulator::drive_to_emission`] and ⟨v, Jᵀ g⟩ by
/// [`Simulator::emission_to_drive_adjoint`], at drives `a` whose channels differ, for fixed
/// `v` and `g` of `n` values.
fn jacobian_against_its_adjoint(sim: &Simulator, n: usize) -> (f64, f64) {
    let a: Vec<f32> = (0..n)
        .map(|i| 0.1 + 0.8 * ((i * 37 % 101) as f32) / 101.0)
        .collect();
    let v: Vec<f32> = (0..n)
        .map(|i| ((i * 53 % 89) as f32) / 89.0 - 0.5)
        .collect();
    let g: Vec<f32> = (0..n).map(|i| ((i * 29 % 83) as f32) / 83.0).collect();
    let eps = 1e-3;
    let shifted = |s: f32| -> Vec<f32> {
        let d: Vec<f32> = a.iter().zip(&v).map(|(x, y)| x + s * eps * y).collect();
        sim.drive_to_emission(&d, false)
    };
    let (f1, f0) = (shifted(1.0), shifted(-1.0));
    let jv: Vec<f32> = f1
        .iter()
        .zip(&f0)
        .map(|(p, q)| (p - q) / (2.0 * eps))
        .collect();
    (
        dot(&jv, &g),
        dot(&v, &sim.emission_to_drive_adjoint(&a, &g)),
    )
}

fn dot(x: &[f32], y: &[f32]) -> f64 {
    x.iter().zip(y).map(|(p, q)| (p * q) as f64).sum::<f64>()
}

#[test]
fn lcd_crosstalk_varies_with_level_and_across_the_frame_and_its_adjoint_matches() {
    let mut scene = crate::rig::builtin("white-plane")
        .expect("built-in")
        .with_resolution(ImageSize::new(40, 30), ImageSize::new(32, 24));
    let plain = Simulator::new(&scene, 1, Phase::Calibration).expect("builds");
    scene.projector.lcd_crosstalk = Some(crate::rig::scene::LcdCrosstalk {
        edge_offset: 0.07,
        across: 0.3,
    });
    let sim = Simulator::new(&scene, 1, Phase::Calibration).expect("builds");
    let pw = 32;
    // Emitted light of one projector pixel in column `x` of the first row for drives `d`.
    let at = |sim: &Simulator, x: usize, d: [f32; 3]| {
        let mut row = vec![0f32; (x + 1) * 3];
        row[x * 3..].copy_from_slice(&d);
        let e = sim.drive_to_emission(&row, false);
        [e[x * 3], e[x * 3 + 1], e[x * 3 + 2]]
    };
    let mid = pw / 2;
    // Green drive alone: its leak into blue (towards shorter wavelengths) is a larger share of
    // its green at a low level than at full; its leak into red a smaller one.
    let share = |x: usize, d: f32| {
        let e = at(&sim, x, [0.0, d, 0.0]);
        (e[2] / e[1], e[0] / e[1])
    };
    let (blue_low, red_low) = share(mid, 0.05);
    let (blue_full, red_full) = share(mid, 1.0);
    let k2_short = (1.0f32 / 0.93).powi(2);
    let k2_long = (1.0f32 / 1.07).powi(2);
    // At full drive in the centre columns (u = ±1/32) the leaks are the mixing's, within the
    // small tilt there.
    let m = &scene.projector.mixing;
    let (mb, mr) = ((m[2][1] / m[1][1]) as f32, (m[0][1] / m[1][1]) as f32);
    assert!((blue_full / mb - 1.0).abs() < 0.02, "{blue_full} vs {mb}");
    assert!((red_full / mr - 1.0).abs() < 0.02, "{red_full} vs {mr}");
    // Near black the shares approach k² of the full-drive ones.
    let expect_low = |k2: f32| k2 + (1.0 - k2) * 0.05;
    assert!(
        (blue_low / blue_full / expect_low(k2_short) - 1.0).abs() < 1e-3,
        "{blue_low} {blue_full}"
    );
    assert!(
        (red_low / red_full / expect_low(k2_long) - 1.0).abs() < 1e-3,
        "{red_low} {red_full}"
    );
    // Across the frame: the leak towards shorter wavelengths grows to the right, the other
    // shrinks; the diagonal does not change.
    let (left, right) = (
        at(&sim, 0, [0.0, 1.0, 0.0]),
        at(&sim, pw - 1, [0.0, 1.0, 0.0]),
    );
    assert!(right[2] > 1.5 * left[2], "{left:?} {right:?}");
    assert!(right[0] < 0.7 * left[0], "{left:?} {right:?}");
    assert_eq!(left[1], right[1]);
    // Without the parameter, nothing of this: the plain projector emits M·d everywhere.
    assert_eq!(
        at(&plain, 0, [0.0, 0.05, 0.0]),
        at(&plain, pw - 1, [0.0, 0.05, 0.0])
    );
    // The adjoint is that of the Jacobian, against a central difference.
    let n = pw * 24 * 3;
    let (lhs, rhs) = jacobian_against_its_adjoint(&sim, n);
    assert!(
        (lhs - rhs).abs() < 1e-3 * lhs.abs().max(1.0),
        "{lhs} vs {rhs}"
    );
    // The map is not homogeneous any more: the Jacobian at the drives does not reproduce it,
    // as it does for the plain projector.
    let a: Vec<f32> = (0..n)
        .map(|i| 0.1 + 0.8 * ((i * 37 % 101) as f32) / 101.0)
        .collect();
    let g: Vec<f32> = (0..n).map(|i| ((i * 29 % 83) as f32) / 83.0).collect();
    let gap = |sim: &Simulator| {
        let jd = dot(&a, &sim.emission_to_drive_adjoint(&a, &g));
        let fd = dot(&sim.drive_to_emission(&a, false), &g);
        (jd - fd).abs() / fd
    };
    assert!(gap(&plain) < 1e-6, "{}", gap(&plain));
    assert!(gap(&sim) > 1e-5, "{}", gap(&sim));
    // Scene files: the parameter round-trips, a typo in it and a value out of range are
    // refused, naming the key.
    let json = serde_json::to_string(&scene).expect("serialises");
    assert!(
        json.contains("\"lcd_crosstalk\":{\"edge_offset\":0.07,\"across\":0.3}"),
        "{json}"
    );
    let back: crate::rig::scene::Scene = serde_json::from_str(&json).expect("parses");
    assert_eq!(back, scene);
    let typo = json.replace("\"across\"", "\"acros\"");
    let err = serde_json::from_str::<crate::rig::scene::Scene>(&typo).expect_err("a typo");
    assert!(err.to_string().contains("acros"), "{err}");
    let mut bad = scene.clone();
    bad.projector.lcd_crosstalk = Some(crate::rig::scene::LcdCrosstalk {
        edge_offset: 0.3,
        across: 0.3,
    });
    let Err(err) = Simulator::new(&bad, 1, Phase::Calibration) else {
        panic!("an edge offset of 0.3 was accepted");
    };
    let err = err.to_string();
    assert!(err.contains("projector.lcd_crosstalk.edge_offset"), "{err}");
}

#[test]
fn subsurface_light_spreads_by_channel_and_is_kept() {
    // A white wall lit on its left half only: with sub-surface scattering, light crosses the
    // edge, furthest in red; on a uniform albedo none is lost away from the frame's edges.
    let mut scene = crate::rig::builtin("white-plane")
        .expect("built-in")
        .with_resolution(ImageSize::new(120, 90), ImageSize::new(100, 75));
    let plain = Simulator::new(&scene, 1, Phase::Calibration).expect("builds");
    scene.subsurface = Some(crate::rig::scene::Subsurface {
        share: 0.8,
        radius_mm: [45.0, 20.0, 0.0],
    });
    let spread = Simulator::new(&scene, 1, Phase::Calibration).expect("builds");
    let ImageSize {
        width: pw,
        height: ph,
    } = plain.projector_size();
    let drive: Vec<f32> = (0..pw * ph)
        .flat_map(|i| [if i % pw < pw / 2 { 1.0 } else { 0.0 }; 3])
        .collect();
    let a = plain.sensor(&plain.drive_to_emission(&drive, false));
    let b = spread.sensor(&spread.drive_to_emission(&drive, false));
    let per_channel = |f: &dyn Fn(f32, f32) -> f32| -> [f64; 3] {
        let mut t = [0f64; 3];
        for (i, (p, q)) in a.iter().zip(&b).enumerate() {
            t[i % 3] += f(*p, *q) as f64;
        }
        t
    };
    let moved = per_channel(&|p, q| (p - q).abs());
    let (before, after) = (per_channel(&|p, _| p), per_channel(&|_, q| q));
    // Blue does not spread: what changes in its signal comes from red and green through the
    // devices' colour mixing (a few per cent).
    assert!(
        moved[0] > 2.0 * moved[1] && moved[1] > 0.0 && moved[2] < 0.05 * moved[0],
        "{moved:?}"
    );
    for c in 0..3 {
        assert!(
            (before[c] - after[c]).abs() < 0.02 * before[c],
            "channel {c}: {before:?} vs {after:?}"
        );
    }
}

#[test]
fn approx_normal_has_unit_variance() {
    let n = 200_000;
    let v: Vec<f64> = (0..n).map(|i| approx_normal(mix64(i)) as f64).collect();
    let mean = v.iter().sum::<f64>() / n as f64;
    let var = v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n as f64;
    assert!(mean.abs() < 0.01, "mean {mean}");
    assert!((var - 1.0).abs() < 0.02, "var {var}");
}

#[test]
fn quantisation_finds_the_level_every_threshold_below_gives() {
    // The bucket table only starts the search: the level is the count of thresholds at or
    // below the signal, near black (where levels crowd), across the range and at its ends.
    let scene = crate::rig::builtin("curved")
        .expect("built-in")
        .with_resolution(ImageSize::new(16, 12), ImageSize::new(16, 12));
    let sim = Simulator::new(&scene, 1, Phase::Calibration).expect("builds");
    let level = |s: f32| sim.thresholds.iter().take_while(|&&t| t <= s).count();
    let mut checked = 0;
    for i in 0..=200_000u32 {
        // Dense near black, then evenly to a little past white.
        let s = if i < 100_000 {
            (i as f32 / 100_000.0).powi(4) * 0.01
        } else {
            (i - 100_000) as f32 / 100_000.0 * 1.01
        };
        for s in [s, f32::from_bits(s.to_bits() + 1)] {
            let want = if s <= 0.0 { 0 } else { level(s).min(255) };
            assert_eq!(usize::from(sim.quantise(s)), want, "signal {s}");
            checked += 1;
        }
        // Each threshold itself and the float below it.
        if let Some(&t) = sim.thresholds.get(i as usize) {
            assert_eq!(usize::from(sim.quantise(t)), level(t), "threshold {t}");
            let below = f32::from_bits(t.to_bits() - 1);
            assert_eq!(usize::from(sim.quantise(below)), level(below), "below {t}");
        }
    }
    assert!(checked > 400_000);
    assert_eq!(sim.quantise(f32::NAN), 0);
    assert_eq!(sim.quantise(-1.0), 0);
    assert_eq!(sim.quantise(1.0), 255);
}
