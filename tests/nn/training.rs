//! CompenNet++ training: it learns, a seed reproduces it, cancelling stops it; a sharded step
//! equals the unsharded one.

use candle_core::{Device, Tensor};
use rand::SeedableRng;
use rand::rngs::ChaCha8Rng;

use super::{max_abs_diff, stack};
use compend::raster::ImageSize;

#[test]
fn compennet_training_learns_reproduces_and_cancels() {
    use compend::nn::compennetpp::{GeometryInit, Variant};
    use compend::nn::train::{Data, Settings, train};
    use std::sync::atomic::AtomicBool;
    let sys = crate::linear::System::new();
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let train_imgs: Vec<_> = (0..12).map(|_| crate::linear::texture(&mut rng)).collect();
    let caps: Vec<_> = train_imgs.iter().map(|t| sys.capture(t)).collect();
    let gray = compend::raster::NetImage::filled(32, 32, [77.0 / 255.0; 3]);
    let data = Data {
        captures: stack(&caps),
        surface: stack(&[sys.capture(&gray)]),
        targets: stack(&train_imgs),
        base: None,
    };
    let theta = [[0.8, 0.0, 0.02], [0.0, 0.83, 0.0]];
    let mut settings = Settings::new(Variant::Faster, 4);
    // From Kaiming noise: this test is about learning, not the pre-initialisation.
    settings.photometric = compend::nn::pretrain::PhotometricInit::Kaiming;
    settings.iters = Some(40);
    settings.batch = Some(4);
    assert_eq!(
        settings.resolved(),
        (4, 40, 32),
        "the lr step scales with --iters (400/500·40)"
    );
    let never = AtomicBool::new(false);
    let aff = || GeometryInit::Affine(theta);
    let go_on = |_: usize, _: &compend::nn::compennetpp::CompenNetPP| Ok(true);
    let (model, report) = train(&data, aff(), &settings, &never, |_, _, _| {}, go_on).unwrap();
    let first: f64 = report.losses[..5].iter().sum::<f64>() / 5.0;
    let last: f64 = report.losses[35..].iter().sum::<f64>() / 5.0;
    assert!(
        last < 0.8 * first,
        "loss should fall: {first:.3} → {last:.3}"
    );
    let out = model
        .forward(&data.captures.narrow(0, 0, 2).unwrap(), &data.surface)
        .unwrap();
    assert_eq!(out.dims(), &[2, 3, 32, 32]);
    // Same seed, same run (a 5-step run: its schedule differs only after its 5th loss).
    let mut short = settings.clone();
    short.iters = Some(5);
    let (_, again) = train(&data, aff(), &short, &never, |_, _, _| {}, go_on).unwrap();
    assert_eq!(report.losses[..5], again.losses[..]);
    let mut other = short.clone();
    other.seed = 5;
    let (_, different) = train(&data, aff(), &other, &never, |_, _, _| {}, go_on).unwrap();
    assert_ne!(
        again.losses, different.losses,
        "another seed draws other weights and batches"
    );
    assert!(!report.stopped_early && report.iterations == 40);
    // A watch sees the model before the first step and after each; stopping it after the
    // third step ends the training there, on the same steps as the full run.
    let mut seen = Vec::new();
    let (_, stopped) = train(
        &data,
        aff(),
        &settings,
        &never,
        |_, _, _| {},
        |done, _| {
            seen.push(done);
            Ok(done < 3)
        },
    )
    .unwrap();
    assert_eq!(seen, [0, 1, 2, 3]);
    assert!(stopped.stopped_early);
    assert_eq!(stopped.iterations, 3);
    assert_eq!(report.losses[..3], stopped.losses[..]);
    // Cancellation before the first step: an error, no model.
    let stop = AtomicBool::new(true);
    let err = train(&data, aff(), &settings, &stop, |_, _, _| {}, go_on)
        .err()
        .expect("cancelled");
    assert!(err.to_string().contains("cancelled"), "{err}");
}

/// A training step split into shards (run in parallel) gives the loss and every variable's
/// gradient of the unsharded step, up to f32 rounding: for a learned geometry with refinement and
/// for a fixed grid, with even and uneven splits.
#[test]
fn sharded_training_step_equals_the_unsharded_one() {
    use compend::nn::compennetpp::{CompenNetPP, GeometryInit};
    let dev = Device::Cpu;
    let (w, h) = (24, 16);
    let fixed = Tensor::rand(-0.9f32, 0.9, (1, h, w, 2), &dev).unwrap();
    for (name, init, refine) in [
        (
            "learned",
            GeometryInit::Affine([[0.8, 0.05, 0.0], [0.0, 0.75, 0.02]]),
            true,
        ),
        ("fixed grid", GeometryInit::Fixed(fixed), false),
    ] {
        let model =
            CompenNetPP::with_width(init, ImageSize::new(w, h), refine, 4, 3, &dev).unwrap();
        for batch in [3, 4] {
            let x = Tensor::rand(0f32, 1.0, (batch, 3, 20, 30), &dev).unwrap();
            let y = Tensor::rand(0f32, 1.0, (batch, 3, h, w), &dev).unwrap();
            let s = Tensor::rand(0f32, 1.0, (1, 3, 20, 30), &dev).unwrap();
            let (v1, g1) = model.gradients(&x, &y, None, &s, 1e-4, 1).unwrap();
            for shards in [2, batch] {
                let (vk, gk) = model.gradients(&x, &y, None, &s, 1e-4, shards).unwrap();
                let what = format!("{name}, batch {batch}, {shards} shards");
                assert!(
                    (v1 - vk).abs() < 1e-6 * v1.abs(),
                    "{what}: loss {v1} vs {vk}"
                );
                let mut compared = 0;
                for (var, t) in model.named_tensors() {
                    if !t.is_variable() {
                        continue;
                    }
                    let (a, b) = (g1.get(&t), gk.get(&t));
                    let (Some(a), Some(b)) = (a, b) else {
                        panic!("{what}: {var} has a gradient in only one ({a:?} / {b:?})");
                    };
                    let scale = a
                        .abs()
                        .unwrap()
                        .max_all()
                        .unwrap()
                        .to_scalar::<f32>()
                        .unwrap();
                    let d = max_abs_diff(a, b);
                    assert!(
                        scale > 0.0 && d <= 1e-4 * f64::from(scale),
                        "{what}: {var} gradient differs by {d} (largest entry {scale})"
                    );
                    compared += 1;
                }
                let expected = if refine { 44 } else { 34 };
                assert_eq!(compared, expected, "{what}: variables with gradients");
            }
        }
    }
}
