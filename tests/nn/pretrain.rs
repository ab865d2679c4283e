//! CompenNet's photometric pre-initialisation: reproducible, round-trips through its files,
//! checks widths; the shipped weights undo a synthetic surface.

use candle_core::{DType, Device, Tensor};

use super::stack;

fn tiny_pretrain(seed: u64) -> compend::nn::pretrain::PretrainSettings {
    compend::nn::pretrain::PretrainSettings {
        width: 4,
        patch: 16,
        image: 24,
        pool: 3,
        batch: 2,
        iters: 4,
        lr_step: 3,
        learning_rate: 1e-3,
        weight_decay: 1e-4,
        seed,
    }
}

#[test]
fn pretraining_is_reproducible_round_trips_and_checks_widths() {
    use compend::nn::pretrain::{PhotometricInit, Pretrained, pretrain};
    use std::sync::atomic::AtomicBool;
    let never = AtomicBool::new(false);
    let run = |seed| pretrain(&tiny_pretrain(seed), &Device::Cpu, &never, |_, _, _| {}).unwrap();
    let (a, b, c) = (run(3), run(3), run(4));
    assert_eq!(a.tensors, b.tensors, "the same seed gives the same weights");
    assert_ne!(a.tensors, c.tensors, "another seed gives other weights");
    assert!(a.meta.first_loss.is_finite() && a.meta.final_loss.is_finite());
    // Every CompenNet variable and nothing else, under the CompenNet++ names.
    let names: Vec<&str> = a.tensors.names().collect();
    assert_eq!(
        names.len(),
        2 * (4 + 3 + 10),
        "weight and bias of 17 convolutions"
    );
    assert!(names.iter().all(|n| n.starts_with("compen.")), "{names:?}");

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("w4.safetensors");
    a.save(&path).unwrap();
    assert!(path.with_extension("json").exists());
    let back = Pretrained::load(&path).unwrap();
    assert_eq!(back.tensors, a.tensors);
    assert_eq!(back.meta.settings, a.meta.settings);
    assert!((back.meta.final_loss - a.meta.final_loss).abs() < 1e-9);
    // Loaded for its own width it resolves; for another width it is refused, naming the file.
    let init = PhotometricInit::File(path.clone());
    assert!(init.resolve(4).unwrap().is_some());
    let err = init.resolve(16).expect_err("width mismatch").to_string();
    assert!(
        err.contains("w4.safetensors") && err.contains("16"),
        "{err}"
    );
    assert_eq!(
        PhotometricInit::Kaiming.resolve(16).unwrap().map(|_| ()),
        None
    );
    // A corrupt weight file and a metadata file of another version are input errors (exit 2).
    std::fs::write(&path, b"not safetensors").unwrap();
    let err = init.resolve(4).expect_err("corrupt");
    assert_eq!(err.exit_code(), 2);
    assert!(err.to_string().contains("w4.safetensors"), "{err}");
    a.save(&path).unwrap();
    let json = path.with_extension("json");
    let text = std::fs::read_to_string(&json).unwrap();
    std::fs::write(
        &json,
        text.replace("\"format_version\": 1", "\"format_version\": 7"),
    )
    .unwrap();
    let err = init.resolve(4).expect_err("old version");
    assert_eq!(err.exit_code(), 2);
    assert!(err.to_string().contains("version 7"), "{err}");
}

/// The shipped weights: they load for both widths, they set every CompenNet variable of a
/// CompenNet++ model, and on synthetic pairs the pre-training never saw (another seed) they
/// undo the surface: at least 10 % below the loss of the input taken as the answer (a network that
/// only copied its input would not be), and far below a Kaiming start.
#[test]
fn shipped_pretrained_weights_undo_the_synthetic_surface() {
    use compend::nn::pretrain::{PREFIX, Pretrained, SURFACE_WEIGHT};
    use compend::patterns::sampling::{Set, sampling_image};
    let side = 128; // the pre-training's image side (its crops are 64²)
    let content: Vec<_> = (0..4)
        .map(|i| sampling_image(9_001, Set::Train, i, side, side))
        .collect();
    let x = stack(&content);
    // A smooth surface, as the pre-training's (made at a quarter of the side and enlarged).
    let s = stack(&[compend::resize::resize(
        &sampling_image(9_002, Set::Test, 0, side / 4, side / 4),
        side,
        side,
        compend::resize::Filter::Bilinear,
    )]);
    let input = x
        .broadcast_sub(&s.affine(SURFACE_WEIGHT, 0.0).unwrap())
        .unwrap()
        .abs()
        .unwrap();
    let score = |t: &Tensor| -> f64 {
        compend::nn::loss::l1_ssim(t, &x)
            .unwrap()
            .to_dtype(DType::F64)
            .unwrap()
            .to_scalar()
            .unwrap()
    };
    let as_is = score(&input);
    for width in [16, 32] {
        let weights = Pretrained::shipped(width).unwrap().expect("shipped");
        assert_eq!(weights.meta.settings.width, width);
        assert!(
            weights.meta.final_loss < 0.7 * weights.meta.first_loss,
            "width {width}: the shipped run's loss fell only {:.3} → {:.3}",
            weights.meta.first_loss,
            weights.meta.final_loss
        );
        let seeded = compend::nn::layers::SeededInit::new(1);
        let vb = seeded.var_builder(DType::F32, &Device::Cpu);
        let net = compend::nn::CompenNet::with_width(vb.pp(PREFIX), width).unwrap();
        let varmap = seeded.finish().unwrap();
        let kaiming = score(&net.forward(&input, &s).unwrap());
        assert_eq!(weights.apply(&varmap).unwrap(), 34);
        let pretrained = score(&net.forward(&input, &s).unwrap());
        eprintln!(
            "width {width}: {pretrained:.3} pre-trained, {as_is:.3} as is, {kaiming:.3} Kaiming"
        );
        assert!(
            pretrained < 0.9 * as_is && pretrained < 0.5 * kaiming,
            "width {width}: loss {pretrained:.3} pre-trained, {as_is:.3} for the input as is, {kaiming:.3} from Kaiming"
        );
    }
}
