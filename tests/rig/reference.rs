//! The reference rows of every scene (uncompensated, geometry-only, oracle) and the oracle's
//! solver, on tiny scenes; the capture timing run by hand.

use super::*;

/// Uncompensated, geometry-only and oracle closed-loop scores on every scene (tiny sizes, two
/// test images). Physics says: the oracle (true model, solved under input clipping) beats the
/// geometry-only warp everywhere, because the warp does no colour correction and every scene
/// bends colours; the geometry-only warp is at least as good as the plain canvas except for
/// noise, and much better where the surface distorts the image a lot (the step); the easy white
/// wall has the best uncompensated result and the highest ceiling, and the dark saturated
/// texture the lowest ceiling.
#[test]
fn reference_rows_are_ordered_as_physics_says() {
    let mut rows = Vec::new();
    for name in rig::BUILTIN {
        let sim = tiny(name, 5);
        let r = references(&sim, 2);
        let msg = format!(
            "{name}: uncompensated {}, geometry-only {}, oracle {}",
            show(&r.uncompensated),
            show(&r.geometry_only),
            show(&r.oracle)
        );
        eprintln!("{msg}");
        assert!(r.oracle.psnr > r.geometry_only.psnr + 1.0, "{msg}");
        assert!(r.oracle.ssim > r.geometry_only.ssim, "{msg}");
        assert!(r.geometry_only.psnr > r.uncompensated.psnr - 0.1, "{msg}");
        if *name == "step" {
            assert!(r.geometry_only.psnr > r.uncompensated.psnr + 3.0, "{msg}");
            assert!(r.geometry_only.ssim > r.uncompensated.ssim + 0.2, "{msg}");
        }
        rows.push((*name, r));
    }
    let get = |n: &str| rows.iter().find(|(m, _)| *m == n).expect("scene scored").1;
    let white = get("white-plane");
    for (name, r) in &rows {
        if *name != "white-plane" {
            assert!(
                white.oracle.psnr > r.oracle.psnr,
                "ceiling of {name} above the white wall's"
            );
            assert!(
                white.uncompensated.psnr > r.uncompensated.psnr,
                "uncompensated {name} above the white wall's"
            );
        }
        if *name != "dark-texture" {
            assert!(
                get("dark-texture").oracle.psnr < r.oracle.psnr - 5.0,
                "{name} vs dark"
            );
        }
    }
    assert!(white.uncompensated.psnr > 17.0 && white.uncompensated.ssim > 0.7);
    assert!(get("textured-plane").oracle.psnr > get("curved-ambient").oracle.psnr);
}

/// The oracle's solver never does worse than its per-pixel start (noise-free, in the metric's
/// terms), and clearly better where the model couples pixels (defocus; highlights and
/// inter-reflection).
#[test]
fn oracle_iterations_improve_on_the_per_pixel_start() {
    for (name, gain_db) in [
        ("white-plane", 0.0),
        ("defocus-noise", 0.3),
        ("specular-corner", 0.5),
    ] {
        let sim = tiny(name, 3);
        let area = area_of(&sim);
        let mask = rig::score::area_mask(&sim, area);
        let des = in_area(&sim, 1, area);
        let psnr = |iterations: usize| {
            let o = sim
                .oracle(&des, &mask, OracleOptions { iterations })
                .expect("oracle");
            let e = sim.expected(&o).expect("render");
            let mse =
                compend::metrics::mse(&e.crop(area).expect("crop"), &des.crop(area).expect("crop"))
                    .expect("mse");
            compend::metrics::psnr_from_mse(mse)
        };
        let (start, solved) = (psnr(0), psnr(OracleOptions::default().iterations));
        eprintln!("{name}: start {start:.2} dB, solved {solved:.2} dB");
        assert!(
            solved >= start + gain_db,
            "{name}: start {start:.2} dB, solved {solved:.2} dB"
        );
    }
}

/// Process CPU time (user + system, all threads) from /proc/self/stat, seconds (Linux).
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // After the command name (in parentheses) come the fields from the 3rd on; utime and stime
    // are the 14th and 15th, in clock ticks (100 per second on Linux).
    let rest = stat.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = rest.split_whitespace().collect();
    let tick = |k: usize| f.get(k).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (tick(11) + tick(12)) / 100.0
}

/// Times one capture at the default 640×480 camera / 800×600 projector: wall time, and CPU
/// time summed over threads (the cost on one core, independent of other load). Run by hand,
/// ideally in an optimised build: `cargo test --release --test integration rig_capture_timing
/// -- --ignored --nocapture`.
#[test]
#[ignore = "timing, run by hand"]
fn rig_capture_timing() {
    for name in rig::BUILTIN {
        let scene = rig::builtin(name).expect("built-in");
        let t0 = std::time::Instant::now();
        let sim = Simulator::new(&scene, 1, Phase::Calibration).expect("builds");
        let prep = t0.elapsed();
        let imgs: Vec<PrjImage> = (0..6).map(|k| on_canvas(&sim, k)).collect();
        let _ = sim.capture(&imgs[0], 0).expect("capture");
        let rounds = 5;
        let (t1, c1) = (std::time::Instant::now(), cpu_seconds());
        for r in 0..rounds {
            for (k, img) in imgs.iter().enumerate() {
                let _ = sim.capture(img, (r * 10 + k) as u64).expect("capture");
            }
        }
        let count = (rounds * imgs.len()) as f64;
        let wall = t1.elapsed().as_secs_f64() / count * 1e3;
        let cpu = (cpu_seconds() - c1) / count * 1e3;
        // The rig as devices: a new pattern per frame (no caching helps).
        let mut rig = rig::VirtualRig::from_simulator(sim);
        let mut cam = rig.clone();
        let t2 = std::time::Instant::now();
        for img in &imgs {
            rig.show(img).expect("show");
            let _ = cam.grab().expect("grab");
        }
        let grab = t2.elapsed().as_secs_f64() / imgs.len() as f64 * 1e3;
        eprintln!(
            "{name:16} prepare {:>7.0} ms  capture {wall:>6.1} ms wall, {cpu:>6.1} ms CPU  \
             show+grab {grab:>6.1} ms",
            prep.as_secs_f64() * 1e3
        );
    }
}
