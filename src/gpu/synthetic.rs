//! Synthetic models of a rung's shapes, for timing its pass (their numbers do not matter, their
//! shapes do): what a climb's live pass ([`super::live`]) and the benchmarks time.

use crate::error::{Error, Result};
use crate::raster::ImageSize;

/// A `linear` model with random per-pixel coefficients, a gently bent grid and a full FOV, for
/// timing (its numbers do not matter, its shapes do): camera `camera`, coefficients and grid on a
/// `network` lattice (the network size or a finer lattice, as training gives).
pub fn synthetic_linear_model(
    camera: ImageSize,
    network: ImageSize,
    seed: u64,
) -> crate::model::Model {
    let model = synthetic_linear(camera, network, seed);
    let meta = synthetic_meta(crate::model::Method::Linear, network, camera);
    crate::model::Model::linear(
        meta,
        crate::raster::Mask::full(camera.width, camera.height),
        model,
    )
}

/// The `linear` model of [`synthetic_linear_model`].
fn synthetic_linear(
    camera: ImageSize,
    network: ImageSize,
    seed: u64,
) -> crate::linear::LinearModel {
    use rand::{RngExt, SeedableRng};

    use crate::linear::{Coefficients, Curves, Geometry, LinearModel};
    use crate::sample::{Grid, pixel_to_norm};

    let mut rng = rand::rngs::ChaCha8Rng::seed_from_u64(seed);
    let ImageSize {
        width: nw,
        height: nh,
    } = network;
    let grid = Grid::from_fn(nw, nh, |x, y| {
        let (u, v) = (pixel_to_norm(x as f32, nw), pixel_to_norm(y as f32, nh));
        [0.8 * u + 0.05 * v * v, 0.8 * v + 0.05 * u * u]
    });
    let data = (0..nw * nh)
        .map(|_| {
            let mut k = [0f32; 12];
            for (i, v) in k.iter_mut().enumerate() {
                *v = if i % 4 == 0 && i < 9 { 1.0 } else { 0.0 } + rng.random_range(-0.1..0.1);
            }
            k
        })
        .collect();
    LinearModel {
        geometry: Geometry::Fixed(grid),
        curves: Curves::default(),
        coeffs: Coefficients {
            width: nw,
            height: nh,
            data,
        },
        camera_size: camera,
        geometry_size: ImageSize::new(nw, nh),
    }
}

/// A set of two projectors side by side with a third of each picture overlapping, each a
/// `linear` model like [`synthetic_linear_model`]'s on a `lattice` lattice, as the joint
/// model of a set ([`crate::joint::JointModel`]) over a `camera` camera, for timing the joint
/// pass.
pub fn synthetic_joint_model(
    camera: ImageSize,
    lattice: ImageSize,
    seed: u64,
) -> Result<crate::joint::JointModel> {
    use crate::sample::{Grid, pixel_to_norm};
    let ImageSize {
        width: nw,
        height: nh,
    } = lattice;
    let models = [(-0.9f32, 0.3f32), (-0.3, 0.9)]
        .into_iter()
        .enumerate()
        .map(|(k, (left, right))| {
            let mut m = synthetic_linear(camera, lattice, seed + k as u64).simplify();
            m.grid = Grid::from_fn(nw, nh, |x, y| {
                let (u, v) = (pixel_to_norm(x as f32, nw), pixel_to_norm(y as f32, nh));
                let t = (u + 1.0) * 0.5;
                [left + (right - left) * t + 0.03 * v * v, 0.8 * v]
            });
            m
        })
        .collect();
    crate::joint::JointModel::new(models, camera)
}

/// A simplified CompenNet++ model with seeded weights (Kaiming normal, zero biases, as a fresh
/// model starts), an affine geometry covering the middle 80% of the camera frame, a full FOV and
/// a smooth gray surface image, for timing: camera `camera`, network `network` (sides divisible
/// by 4), the widths and refinement of `variant`. The surface branch is folded once here (on the
/// CPU, candle), as after training.
pub fn synthetic_compennet_model(
    camera: ImageSize,
    network: ImageSize,
    variant: crate::nn::compennetpp::Variant,
    seed: u64,
) -> Result<crate::model::Model> {
    let (net, surface) = synthetic_network(camera, network, variant, seed)?;
    let meta = synthetic_meta(method_of(variant)?, network, camera);
    crate::model::Model::compennet(
        meta,
        crate::raster::Mask::full(camera.width, camera.height),
        net,
        surface,
    )
}

/// A residual rung's model for timing (`variant` one of the residual rungs): the
/// [`synthetic_linear_model`]'s `linear` part on `lattice`, and a correction network as
/// [`synthetic_compennet_model`]'s, on the data root's `network` divided by the variant's
/// divisor, its last layer at zero as a fresh rung starts.
pub fn synthetic_residual_model(
    camera: ImageSize,
    lattice: ImageSize,
    network: ImageSize,
    variant: crate::nn::compennetpp::Variant,
    seed: u64,
) -> Result<crate::model::Model> {
    if !variant.residual() {
        return Err(Error::Input(format!(
            "{}: not a residual rung",
            variant.method()
        )));
    }
    let div = variant.network_divisor();
    let correction = ImageSize::new(network.width / div, network.height / div);
    let (mut net, surface) = synthetic_network(camera, correction, variant, seed)?;
    net.make_residual()
        .map_err(|e| Error::Failed(format!("synthetic {}: {e}", variant.method())))?;
    let meta = synthetic_meta(method_of(variant)?, lattice, camera);
    crate::model::Model::residual(
        meta,
        crate::raster::Mask::full(camera.width, camera.height),
        synthetic_linear(camera, lattice, seed),
        net,
        surface,
    )
}

/// The seeded network of [`synthetic_compennet_model`] and its surface image.
fn synthetic_network(
    camera: ImageSize,
    network: ImageSize,
    variant: crate::nn::compennetpp::Variant,
    seed: u64,
) -> Result<(crate::nn::compennetpp::CompenNetPP, crate::raster::CamImage)> {
    use crate::nn::compennetpp::{CompenNetPP, GeometryInit};
    use crate::raster::CamImage;

    if !network.width.is_multiple_of(4)
        || !network.height.is_multiple_of(4)
        || network.width == 0
        || network.height == 0
    {
        return Err(Error::Input(format!(
            "CompenNet network size {}: sides must be positive multiples of 4",
            network
        )));
    }
    let net = CompenNetPP::with_width(
        GeometryInit::Affine([[0.8, 0.0, 0.0], [0.0, 0.8, 0.0]]),
        network,
        variant.refine(),
        variant.width(),
        seed,
        &candle_core::Device::Cpu,
    )
    .map_err(|e| Error::Failed(format!("synthetic CompenNet++: {e}")))?;
    let ImageSize {
        width: cw,
        height: ch,
    } = camera;
    // A smooth gray-ish surface capture, camera pixels, values in [0.2, 0.4].
    let surface = CamImage::from_vec(
        cw,
        ch,
        (0..cw * ch)
            .flat_map(|i| {
                let (x, y) = ((i % cw) as f32 / cw as f32, (i / cw) as f32 / ch as f32);
                [0.3 + 0.1 * x - 0.05 * y, 0.3, 0.3 - 0.1 * x + 0.05 * y]
            })
            .collect(),
    )?;
    Ok((net, surface))
}

/// The method of `variant`.
fn method_of(variant: crate::nn::compennetpp::Variant) -> Result<crate::model::Method> {
    crate::model::Method::from_name(variant.method())
        .ok_or_else(|| crate::Error::Shape(format!("no method named {}", variant.method())))
}

/// The record of a synthetic model of `method` whose output is `network` pixels.
fn synthetic_meta(
    method: crate::model::Method,
    network: ImageSize,
    camera: ImageSize,
) -> crate::model::store::ModelMeta {
    use crate::model::store::{FORMAT_VERSION, ModelMeta};

    ModelMeta {
        format_version: FORMAT_VERSION,
        method,
        network_size: network,
        camera_size: camera,
        canvas: None,
        training: Default::default(),
        metrics: serde_json::Value::Null,
        timings: Default::default(),
        written_by: concat!("compend ", env!("CARGO_PKG_VERSION"), " (synthetic)").into(),
        weights_sha256: None,
        calibration: None,
    }
}
