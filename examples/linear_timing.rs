// Throwaway timing harness (not committed): linear fit at 640x480 / 48 pairs / 256².
use compend::linear::{FitSettings, fit};
use compend::patterns::{Set, sampling_image};
use compend::raster::{CamImage, NetImage, PrjImage};
use compend::rig::{Phase, Simulator, builtin};
use std::time::Instant;

fn main() {
    let scene = std::env::args().nth(1).unwrap_or("curved".into());
    let n: usize = std::env::args()
        .nth(2)
        .map(|s| s.parse().unwrap())
        .unwrap_or(48);
    let sim = Simulator::new(&builtin(&scene).unwrap(), 1, Phase::Calibration).unwrap();
    let (pw, ph) = sim.projector_size();
    let t = Instant::now();
    let mut caps: Vec<CamImage> = vec![];
    let mut tg: Vec<NetImage> = vec![];
    for i in 0..n {
        let x = sampling_image(5, Set::Train, i, 256, 256);
        let p: PrjImage = compend::resize::resize_bilinear(&x, pw, ph);
        caps.push(sim.capture(&p, i as u64).unwrap());
        tg.push(x.into_space());
    }
    eprintln!(
        "{} captures in {:.2}s ({:?})",
        n,
        t.elapsed().as_secs_f64(),
        sim.camera_size()
    );
    let black = sim.capture(&PrjImage::new(pw, ph), 1000).unwrap();
    let white = sim
        .capture(&PrjImage::filled(pw, ph, [1.0; 3]), 1001)
        .unwrap();
    let fov = compend::fov::fov_mask(&black, &white, "x").unwrap();
    let theta = compend::fov::affine_from_box(fov.bbox, black.size()).unwrap();
    let caps: Vec<CamImage> = caps.iter().map(|c| c.masked(&fov.mask).unwrap()).collect();
    let t = Instant::now();
    let (m, r) = fit(
        &caps,
        &tg,
        compend::warp::Warp::from_affine(theta),
        &FitSettings::default(),
        |_, _, _| {},
    )
    .unwrap();
    eprintln!(
        "fit {:.2}s loss {:.3e} first {:.3e} last {:.3e} curves {:?}",
        t.elapsed().as_secs_f64(),
        r.final_loss,
        r.loss_history[0],
        r.loss_history.last().unwrap(),
        m.curves
    );
    // held-out paper protocol
    let s = m.simplify();
    let mut acc = compend::metrics::Accumulator::default();
    let mut unc = compend::metrics::Accumulator::default();
    for i in 0..8 {
        let x = sampling_image(5, Set::Test, i, 256, 256);
        let p: PrjImage = compend::resize::resize_bilinear(&x, pw, ph);
        let c = sim
            .capture(&p, 2000 + i as u64)
            .unwrap()
            .masked(&fov.mask)
            .unwrap();
        let xn: NetImage = x.into_space();
        acc.add(&s.apply(&c), &xn).unwrap();
        unc.add(&compend::sample::grid_sample(&c, &s.grid), &xn)
            .unwrap();
    }
    eprintln!(
        "paper protocol: {:?}\nuncompensated: {:?}",
        acc.finish().unwrap(),
        unc.finish().unwrap()
    );
}
