//! A trained model as the offline commands and playback see it: load it from a model directory,
//! map camera-space images to network-space projector images, save it.

use std::path::Path;

use crate::error::{Error, Result};
use crate::linear::LinearModel;
use crate::tensors::Tensors;
use store::ModelMeta;

pub mod set;
pub mod store;

pub use crate::method::{Method, MethodChoice};
use crate::raster::{CamImage, Camera, ImageSize, Mask, NetImage, Network};
use crate::sample::Grid;

/// A loaded model with its metadata and the projector FOV mask its inputs are masked with.
#[derive(Debug)]
pub struct Model {
    pub meta: ModelMeta,
    /// Projector FOV in camera space; inputs are masked by it, as in training.
    pub fov: Mask<Camera>,
    pub kind: Kind,
}

pub enum Kind {
    /// `linear` and `linear-sl` share the representation; they differ in how geometry was found.
    Linear {
        model: Box<LinearModel>,
        simplified: crate::linear::SimplifiedLinear,
    },
    /// The CompenNet++ variants: the full network (CPU, candle), the gray surface capture it
    /// conditions on (camera space, masked), and its grid baked for the geometry-only row.
    CompenNet {
        net: Box<crate::nn::compennetpp::CompenNetPP>,
        surface: CamImage,
        grid: Grid<Network, Camera>,
        /// Baked grid and folded surface branch: what runs per frame.
        simplified: Box<crate::nn::compennetpp::SimplifiedCompenNet>,
    },
    /// A residual rung (`compennet++-res`, `compennet++-res-full`): a `linear` model (its output
    /// lattice is the model's) plus a CompenNet on `linear`'s grid (CPU-sized, or full-size),
    /// whose signed correction (on its network) is stretched over the lattice and added.
    Residual {
        linear: Box<LinearModel>,
        base: crate::linear::SimplifiedLinear,
        net: Box<crate::nn::compennetpp::CompenNetPP>,
        surface: CamImage,
        correction: Box<crate::nn::compennetpp::SimplifiedCompenNet>,
    },
}

/// Prefix of the `linear` part's tensors in a residual rung's model directory.
const RESIDUAL_LINEAR: &str = "linear.";

impl std::fmt::Debug for Kind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Kind::Linear { .. } => write!(f, "Kind::Linear"),
            Kind::CompenNet { .. } => write!(f, "Kind::CompenNet"),
            Kind::Residual { .. } => write!(f, "Kind::Residual"),
        }
    }
}

impl Model {
    /// The range of camera values content is mapped into when this model plays: the one
    /// `compend calibrate` measured for it, else the full range.
    pub fn display_range(&self) -> crate::fov::DisplayRange {
        self.meta
            .calibration
            .as_ref()
            .and_then(|c| c.display_range)
            .unwrap_or(crate::fov::DisplayRange::FULL)
    }

    pub fn linear(meta: ModelMeta, fov: Mask<Camera>, model: LinearModel) -> Self {
        let simplified = model.simplify();
        Self {
            meta,
            fov,
            kind: Kind::Linear {
                model: Box::new(model),
                simplified,
            },
        }
    }

    /// A CompenNet++ model; `surface` is the masked gray surface capture (camera space).
    pub fn compennet(
        meta: ModelMeta,
        fov: Mask<Camera>,
        net: crate::nn::compennetpp::CompenNetPP,
        surface: CamImage,
    ) -> Result<Self> {
        let grid = baked_grid(&net, meta.network_size)?;
        let simplified = net.simplify(&crate::nn::images_to_tensor(std::slice::from_ref(
            &surface,
        ))?)?;
        Ok(Self {
            meta,
            fov,
            kind: Kind::CompenNet {
                net: Box::new(net),
                surface,
                grid,
                simplified: Box::new(simplified),
            },
        })
    }

    /// A residual rung's model: `linear` and the correction network `net` trained on top of
    /// it; `surface` is the masked gray surface capture (camera space).
    pub fn residual(
        meta: ModelMeta,
        fov: Mask<Camera>,
        linear: LinearModel,
        net: crate::nn::compennetpp::CompenNetPP,
        surface: CamImage,
    ) -> Result<Self> {
        let correction = net.simplify(&crate::nn::images_to_tensor(std::slice::from_ref(
            &surface,
        ))?)?;
        Ok(Self {
            meta,
            fov,
            kind: Kind::Residual {
                base: linear.simplify(),
                linear: Box::new(linear),
                net: Box::new(net),
                surface,
                correction: Box::new(correction),
            },
        })
    }

    /// Loads a model directory; an unknown method, a version mismatch, a missing or mis-shaped
    /// tensor is an input error naming the file.
    pub fn load(dir: &Path) -> Result<Self> {
        if set::SetModel::is_set(dir) {
            return Err(Error::Input(format!(
                "{}: the model of a set of projectors ({}): play it with `compend play --model \
                 {}` on a rig of that set; one projector's model is in its `projector-N` folder",
                dir.display(),
                store::SET_FILE,
                dir.display()
            )));
        }
        if !dir.exists() {
            return Err(Error::Missing {
                path: dir.to_path_buf(),
                expected: format!(
                    "a model directory holding {} and {}",
                    store::META_FILE,
                    store::WEIGHTS_FILE
                ),
            });
        }
        let (meta, tensors) = store::load(dir)?;
        let file = dir.join(store::WEIGHTS_FILE);
        let ImageSize {
            width: cw,
            height: ch,
        } = meta.camera_size;
        let fov = tensors.get("fov_mask", &[ch, cw], &file)?;
        let fov = Mask::from_vec(cw, ch, fov.iter().map(|&v| v >= 0.5).collect())?;
        match crate::nn::compennetpp::Variant::from_method(meta.method.name()) {
            None => {
                let model = LinearModel::from_tensors(
                    &tensors,
                    meta.network_size,
                    meta.camera_size,
                    &file,
                )?;
                Ok(Self::linear(meta, fov, model))
            }
            Some(variant) => {
                let surface = tensors.get("surface", &[ch, cw, 3], &file)?;
                let surface = CamImage::from_vec(cw, ch, surface.to_vec())?;
                // The residual rung's network is on the coarser grid it stores; its output
                // lattice (the model's network size) is the `linear` part's.
                let net_size = if variant.residual() {
                    match tensors.shape(crate::nn::compennetpp::FIXED_GRID) {
                        Some(&[1, h, w, 2]) => ImageSize::new(w, h),
                        _ => {
                            return Err(Error::Input(format!(
                                "{}: tensor `{}` is missing or not (1, H, W, 2)",
                                file.display(),
                                crate::nn::compennetpp::FIXED_GRID
                            )));
                        }
                    }
                } else {
                    meta.network_size
                };
                let net = crate::nn::compennetpp::CompenNetPP::restore(
                    net_size,
                    variant,
                    &candle_core::Device::Cpu,
                    |name, shape| tensors.get(name, shape, &file).map(|v| v.to_vec()),
                )?;
                if variant.residual() {
                    let linear = LinearModel::from_tensors(
                        &tensors.under(RESIDUAL_LINEAR),
                        meta.network_size,
                        meta.camera_size,
                        &file,
                    )?;
                    return Self::residual(meta, fov, linear, net, surface);
                }
                Self::compennet(meta, fov, net, surface)
            }
        }
    }

    /// Saves the model directory atomically (an existing model is replaced only when complete).
    pub fn save(&self, dir: &Path) -> Result<()> {
        let network_tensors =
            |net: &crate::nn::compennetpp::CompenNetPP, surface: &CamImage| -> Result<Tensors> {
                let mut t = Tensors::default();
                for (name, value) in net.named_tensors() {
                    let dims = value.dims().to_vec();
                    let data: Vec<f32> = value.flatten_all()?.to_vec1()?;
                    t.insert(&name, dims, data)?;
                }
                let ImageSize {
                    width: w,
                    height: h,
                } = surface.size();
                t.insert("surface", vec![h, w, 3], surface.data().to_vec())?;
                Ok(t)
            };
        let mut tensors: Tensors = match &self.kind {
            Kind::Linear { model, .. } => model.to_tensors()?,
            Kind::CompenNet { net, surface, .. } => network_tensors(net, surface)?,
            Kind::Residual {
                linear,
                net,
                surface,
                ..
            } => {
                let mut t = network_tensors(net, surface)?;
                t.insert_all(RESIDUAL_LINEAR, linear.to_tensors()?);
                t
            }
        };
        let ImageSize {
            width: cw,
            height: ch,
        } = self.fov.size();
        tensors.insert(
            "fov_mask",
            vec![ch, cw],
            self.fov
                .data()
                .iter()
                .map(|&b| if b { 1.0 } else { 0.0 })
                .collect(),
        )?;
        store::save(dir, &self.meta, &tensors)
    }

    /// Camera size (width, height), camera pixels.
    pub fn camera_size(&self) -> ImageSize {
        self.meta.camera_size
    }

    /// Network size (width, height), network pixels.
    pub fn network_size(&self) -> ImageSize {
        self.meta.network_size
    }

    /// The `linear` model a residual rung's model stands on, and its simplified form (what
    /// [`Model::infer`] applies); `None` for the other rungs.
    pub fn residual_base(&self) -> Option<(&LinearModel, &crate::linear::SimplifiedLinear)> {
        match &self.kind {
            Kind::Residual { linear, base, .. } => Some((linear, base)),
            _ => None,
        }
    }

    /// The baked sampling grid from network pixels into the camera image.
    pub fn grid(&self) -> &Grid<Network, Camera> {
        match &self.kind {
            Kind::Linear { simplified, .. } => &simplified.grid,
            Kind::CompenNet { grid, .. } => grid,
            Kind::Residual { base, .. } => &base.grid,
        }
    }

    fn check_input(&self, img: &CamImage) -> Result<()> {
        if img.size() != self.camera_size() {
            return Err(Error::Shape(format!(
                "model expects {} camera images, got {}x{}",
                self.camera_size(),
                img.width(),
                img.height()
            )));
        }
        Ok(())
    }

    /// π†: a camera-space image (a capture x̃ or a desired viewer image z') to the network-space
    /// projector image, the input masked by the FOV mask first.
    pub fn infer(&self, img: &CamImage) -> Result<NetImage> {
        self.check_input(img)?;
        let masked = img.masked(&self.fov)?;
        match &self.kind {
            Kind::Linear { simplified, .. } => Ok(simplified.apply(&masked)),
            Kind::CompenNet { simplified, .. } => {
                let x = crate::nn::images_to_tensor(std::slice::from_ref(&masked))?;
                let out = simplified.forward(&x)?;
                Ok(crate::nn::tensor_to_image(&out, 0)?)
            }
            Kind::Residual {
                base, correction, ..
            } => {
                let x = crate::nn::images_to_tensor(std::slice::from_ref(&masked))?;
                let r: NetImage = crate::nn::tensor_to_image(&correction.forward(&x)?, 0)?;
                add_correction(&base.apply(&masked), &r)
            }
        }
    }

    /// The geometry alone: the masked camera image warped to network space (the paper's
    /// "uncompensated" row compares these with the projector inputs).
    pub fn warp_only(&self, img: &CamImage) -> Result<NetImage> {
        self.check_input(img)?;
        let masked = img.masked(&self.fov)?;
        Ok(crate::sample::grid_sample(&masked, self.grid()))
    }
}

/// The paper protocol (docs/architecture.md, "Models") on test pairs: the model's output for each capture
/// against the projector input, and the "uncompensated" row (captures warped by the model's own
/// grid against the inputs). Returns (compensated, uncompensated).
pub fn paper_protocol(
    model: &Model,
    pairs: &crate::dataset::Pairs,
) -> Result<(crate::metrics::Scores, crate::metrics::Scores)> {
    let (mut comp, mut uncomp) = (
        crate::metrics::Accumulator::default(),
        crate::metrics::Accumulator::default(),
    );
    for (cap, input) in pairs.captures.iter().zip(&pairs.inputs) {
        let target: NetImage = input.clone().into_space();
        comp.add(&at_size(model.infer(cap)?, target.size()), &target)?;
        uncomp.add(&at_size(model.warp_only(cap)?, target.size()), &target)?;
    }
    Ok((comp.finish()?, uncomp.finish()?))
}

/// The camera-space score of a linear rung on held-out pairs: how well its forward model
/// ([`crate::linear::SimplifiedLinear::predict_capture`]) predicts each capture from its
/// projector image, the mean squared error over the lattice pixels whose camera position lies inside the
/// projector FOV (camera values, encoded as captured, sampled through the model's grid). Where
/// the paper protocol compares projector values, and so weighs most the pixels on a dark
/// surface, where a small error of the camera's is a large one of the projector's, this
/// compares what the camera sees, as a closed-loop score does. `None` for a CompenNet++ model,
/// which has no forward model.
pub fn forward_mse(model: &Model, pairs: &crate::dataset::Pairs) -> Result<Option<f64>> {
    forward_mse_in(model, pairs, None)
}

/// [`forward_mse`] over the lattice pixels whose camera position (nearest camera pixel) also
/// lies inside `area` (camera pixels), when given: a closed-loop pair's desired view fills
/// only the displayable area, and around it the camera sees the projector's black, which any
/// model predicts.
pub fn forward_mse_in(
    model: &Model,
    pairs: &crate::dataset::Pairs,
    area: Option<crate::raster::Rect>,
) -> Result<Option<f64>> {
    let Kind::Linear { simplified, .. } = &model.kind else {
        return Ok(None);
    };
    let lattice = simplified.grid.size();
    let camera = model.fov.size();
    // Normalised camera coordinates (align-corners) to the nearest camera pixel.
    let to_pixel = |g: f32, n: usize| ((g + 1.0) * 0.5 * (n.max(2) - 1) as f32).round();
    let in_area: Vec<bool> = simplified
        .grid
        .data()
        .iter()
        .map(|&[gx, gy]| {
            area.is_none_or(|a| {
                let (x, y) = (to_pixel(gx, camera.width), to_pixel(gy, camera.height));
                x >= 0.0 && y >= 0.0 && a.contains(x as usize, y as usize)
            })
        })
        .collect();
    let fov = CamImage::from_vec(
        model.fov.width(),
        model.fov.height(),
        model
            .fov
            .data()
            .iter()
            .flat_map(|&v| [f32::from(u8::from(v)); 3])
            .collect(),
    )?;
    let inside = crate::sample::grid_sample(&fov, &simplified.grid);
    let (mut sq, mut values) = (0f64, 0usize);
    for (cap, input) in pairs.captures.iter().zip(&pairs.inputs) {
        let seen = crate::sample::grid_sample(&cap.masked(&model.fov)?, &simplified.grid);
        let shown: NetImage = input.clone().into_space();
        let shown = crate::resize::resize_bilinear(&shown, lattice.width, lattice.height);
        let predicted = simplified.predict_capture(&shown)?;
        for (((p, s), w), &kept) in predicted
            .data()
            .chunks_exact(3)
            .zip(seen.data().chunks_exact(3))
            .zip(inside.data().chunks_exact(3))
            .zip(&in_area)
        {
            if !kept || w[0] < 0.999 || p.iter().any(|v| !v.is_finite()) {
                continue;
            }
            for c in 0..3 {
                sq += f64::from(p[c] - s[c]).powi(2);
            }
            values += 3;
        }
    }
    if values == 0 {
        return Err(Error::Input(match area {
            None => "no lattice pixel of the model falls inside its projector FOV: nothing to \
                     score"
                .into(),
            Some(a) => format!(
                "no lattice pixel of the model falls inside its projector FOV and the area {a} \
                 (camera pixels): nothing to score"
            ),
        }));
    }
    Ok(Some(sq / values as f64))
}

/// The residual rung's output: `linear`'s image (network pixels on its lattice) plus the
/// correction `r` (network pixels, a coarser network over the same canvas) stretched over the
/// lattice bilinearly (half-pixel centres, as the canvas stretches), clamped to [0, 1]. The CPU
/// reference of the GPU pass's residual stage.
pub fn add_correction(linear: &NetImage, r: &NetImage) -> Result<NetImage> {
    let up = crate::resize::resize_bilinear(r, linear.width(), linear.height());
    let data = linear
        .data()
        .iter()
        .zip(up.data())
        .map(|(a, b)| (a + b).clamp(0.0, 1.0))
        .collect();
    NetImage::from_vec(linear.width(), linear.height(), data)
}

/// A model output brought to `size` for scoring against network-space images (a `linear`
/// model's output lattice can be finer than the network; the paper protocol scores at the
/// network size): unchanged when it has that size, else the network-size image whose canvas
/// stretch shows the same ([`crate::resize::unstretch`]).
pub fn at_size(img: NetImage, size: ImageSize) -> NetImage {
    if img.size() == size {
        img
    } else {
        crate::resize::unstretch(&img, size.width, size.height)
    }
}

/// The network's current sampling grid as a core grid.
fn baked_grid(
    net: &crate::nn::compennetpp::CompenNetPP,
    ImageSize {
        width: w,
        height: h,
    }: ImageSize,
) -> Result<Grid<Network, Camera>> {
    let g: Vec<f32> = net.warp.grid()?.flatten_all()?.to_vec1()?;
    Grid::from_vec(w, h, g.chunks_exact(2).map(|c| [c[0], c[1]]).collect())
}
