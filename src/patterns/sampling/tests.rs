//! Unit tests of the sampling-image generator.

use super::compose::hsv_to_rgb;
use super::field::value_noise;
use super::*;
use crate::raster::ImageSize;

#[test]
fn deterministic_and_independent_of_other_indices() {
    let a = sampling_image(3, Set::Train, 5, 24, 16);
    let b = sampling_image(3, Set::Train, 5, 24, 16);
    assert_eq!(a, b);
    assert_eq!(a.size(), ImageSize::new(24, 16));
    assert_ne!(a, sampling_image(3, Set::Train, 6, 24, 16));
    assert_ne!(a, sampling_image(3, Set::Test, 5, 24, 16));
    assert_ne!(a, sampling_image(4, Set::Train, 5, 24, 16));
    assert!(a.data().iter().all(|v| (0.0..=1.0).contains(v)));
}

#[test]
fn hsv_primaries() {
    let close = |a: [f32; 3], b: [f32; 3]| a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-5);
    assert!(close(hsv_to_rgb(0.0, 1.0, 1.0), [1.0, 0.0, 0.0]));
    assert!(close(hsv_to_rgb(1.0 / 3.0, 1.0, 1.0), [0.0, 1.0, 0.0]));
    assert!(close(hsv_to_rgb(2.0 / 3.0, 1.0, 1.0), [0.0, 0.0, 1.0]));
    assert!(close(hsv_to_rgb(0.5, 0.0, 0.25), [0.25, 0.25, 0.25]));
}

#[test]
fn value_noise_is_continuous_and_bounded() {
    let mut prev = value_noise(7, [0.0, 0.3]);
    for i in 1..2000 {
        let v = value_noise(7, [i as f32 * 0.002, 0.3]);
        assert!((0.0..=1.0).contains(&v));
        assert!((v - prev).abs() < 0.02, "jump at {i}: {prev} → {v}");
        prev = v;
    }
}
