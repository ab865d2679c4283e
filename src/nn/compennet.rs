//! CompenNet (the photometric part `F†` of CompenNet++, docs/architecture.md, "Models") in
//! candle.
//!
//! Input: the (warped) capture `x` (N, 3, H, W) in network space and the (warped) surface image
//! `s` (1 or N, 3, H, W); output: the projector image in [0, 1], same size. H and W must be
//! divisible by 4. The surface branch depends only on `s`: compute it once with
//! [`CompenNet::surface`] and reuse the features for every batch element ([`CompenNet::forward_with`]).

use candle_core::{Module, Result, Tensor};
use candle_nn::{Conv2d, ConvTranspose2d, VarBuilder};

use super::layers::{WeightInit, conv, tconv};

/// The channel width of the paper's CompenNet: the first encoder layer's; the others are 2×, 4×
/// and 8× it. Narrower networks (the CPU rung) keep the same shape with a smaller base.
pub const PAPER_WIDTH: usize = 32;

/// The surface branch: s̃ → s1 (32, H/2), s2 (64, H/4), s3 (128, H/4), s4 (256, H/4) at the
/// paper's width.
#[derive(Clone, Debug)]
pub struct SurfaceBranch {
    conv1: Conv2d,
    conv2: Conv2d,
    conv3: Conv2d,
    conv4: Conv2d,
}

/// The surface features added into the backbone's pre-activations (constant once trained: the
/// simplified model stores them as bias maps).
#[derive(Clone, Debug)]
pub struct SurfaceFeatures {
    pub s1: Tensor,
    pub s2: Tensor,
    pub s3: Tensor,
    pub s4: Tensor,
}

impl SurfaceBranch {
    /// `w`: the base channel width ([`PAPER_WIDTH`] for the paper's network).
    pub fn new(vb: VarBuilder, w: usize) -> Result<Self> {
        let k = WeightInit::KaimingNormal;
        Ok(Self {
            conv1: conv(vb.pp("conv1_s"), 3, w, 3, 2, 1, k)?,
            conv2: conv(vb.pp("conv2_s"), w, 2 * w, 3, 2, 1, k)?,
            conv3: conv(vb.pp("conv3_s"), 2 * w, 4 * w, 3, 1, 1, k)?,
            conv4: conv(vb.pp("conv4_s"), 4 * w, 8 * w, 3, 1, 1, k)?,
        })
    }

    pub fn forward(&self, s: &Tensor) -> Result<SurfaceFeatures> {
        let s1 = super::conv::relu(&super::conv::conv2d(&self.conv1, s)?)?;
        let s2 = super::conv::relu(&super::conv::conv2d(&self.conv2, &s1)?)?;
        let s3 = super::conv::relu(&super::conv::conv2d(&self.conv3, &s2)?)?;
        let s4 = super::conv::relu(&super::conv::conv2d(&self.conv4, &s3)?)?;
        Ok(SurfaceFeatures { s1, s2, s3, s4 })
    }
}

/// The skip path from the input: three 3×3 convolutions 3 → 3, each followed by ReLU.
#[derive(Clone, Debug)]
pub struct Skip1 {
    pub convs: [Conv2d; 3],
}

impl Skip1 {
    pub fn new(vb: VarBuilder) -> Result<Self> {
        let k = WeightInit::KaimingNormal;
        Ok(Self {
            convs: [
                conv(vb.pp("0"), 3, 3, 3, 1, 1, k)?,
                conv(vb.pp("1"), 3, 3, 3, 1, 1, k)?,
                conv(vb.pp("2"), 3, 3, 3, 1, 1, k)?,
            ],
        })
    }
}

impl Module for Skip1 {
    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let mut r = x.clone();
        for c in &self.convs {
            r = super::conv::relu(&super::conv::conv2d(c, &r)?)?;
        }
        Ok(r)
    }
}

/// The backbone: encoder with surface features added, decoder with skips. Its layers are public
/// so that other executors (the GPU compensation pass) can read the weights.
#[derive(Clone, Debug)]
pub struct Backbone {
    pub skip1: Skip1,
    pub conv1: Conv2d,
    pub skip2: Conv2d,
    pub conv2: Conv2d,
    pub skip3: Conv2d,
    pub conv3: Conv2d,
    pub conv4: Conv2d,
    pub conv5: Conv2d,
    pub tconv1: ConvTranspose2d,
    pub tconv2: ConvTranspose2d,
    pub conv6: Conv2d,
    /// The residual rung's tail: the output is `conv6` alone, a signed correction (no input
    /// skip, no ReLU, no clamp); otherwise the paper's `clamp(relu(conv6 + skip1(x)), 0, 1)`.
    pub residual: bool,
}

impl Backbone {
    /// `w`: the base channel width ([`PAPER_WIDTH`] for the paper's network).
    pub fn new(vb: VarBuilder, w: usize) -> Result<Self> {
        let k = WeightInit::KaimingNormal;
        Ok(Self {
            skip1: Skip1::new(vb.pp("skip1"))?,
            conv1: conv(vb.pp("conv1"), 3, w, 3, 2, 1, k)?,
            skip2: conv(vb.pp("skip2"), w, 2 * w, 1, 1, 0, k)?,
            conv2: conv(vb.pp("conv2"), w, 2 * w, 3, 2, 1, k)?,
            skip3: conv(vb.pp("skip3"), 2 * w, 4 * w, 1, 1, 0, k)?,
            conv3: conv(vb.pp("conv3"), 2 * w, 4 * w, 3, 1, 1, k)?,
            conv4: conv(vb.pp("conv4"), 4 * w, 8 * w, 3, 1, 1, k)?,
            conv5: conv(vb.pp("conv5"), 8 * w, 4 * w, 3, 1, 1, k)?,
            tconv1: tconv(vb.pp("tconv1"), 4 * w, 2 * w, 2, k)?,
            tconv2: tconv(vb.pp("tconv2"), 2 * w, w, 2, k)?,
            conv6: conv(vb.pp("conv6"), w, 3, 3, 1, 1, k)?,
            residual: false,
        })
    }

    /// `x` (N, 3, H, W); the surface features broadcast over the batch.
    pub fn forward(&self, x: &Tensor, s: &SurfaceFeatures) -> Result<Tensor> {
        use super::conv::{add_relu, conv_transpose2d, conv2d, relu};
        let a1 = add_relu(&conv2d(&self.conv1, x)?, &s.s1)?;
        let res2 = conv2d(&self.skip2, &a1)?;
        let a2 = add_relu(&conv2d(&self.conv2, &a1)?, &s.s2)?;
        let res3 = conv2d(&self.skip3, &a2)?;
        let a3 = add_relu(&conv2d(&self.conv3, &a2)?, &s.s3)?;
        let a4 = add_relu(&conv2d(&self.conv4, &a3)?, &s.s4)?;
        let a5 = add_relu(&conv2d(&self.conv5, &a4)?, &res3)?;
        let a6 = add_relu(&conv_transpose2d(&self.tconv1, &a5)?, &res2)?;
        let a7 = relu(&conv_transpose2d(&self.tconv2, &a6)?)?;
        if self.residual {
            return conv2d(&self.conv6, &a7);
        }
        let res1 = self.skip1.forward(x)?;
        add_relu(&conv2d(&self.conv6, &a7)?, &res1)?.clamp(0.0, 1.0)
    }
}

/// CompenNet: surface branch + backbone.
#[derive(Clone, Debug)]
pub struct CompenNet {
    pub surface: SurfaceBranch,
    pub backbone: Backbone,
}

impl CompenNet {
    /// Variables are created under `vb`'s path: `surface.conv1_s.weight`, `backbone.conv1.bias`, ….
    pub fn new(vb: VarBuilder) -> Result<Self> {
        Self::with_width(vb, PAPER_WIDTH)
    }

    /// The same design with base channel width `w` (the paper's is [`PAPER_WIDTH`]).
    pub fn with_width(vb: VarBuilder, w: usize) -> Result<Self> {
        Ok(Self {
            surface: SurfaceBranch::new(vb.pp("surface"), w)?,
            backbone: Backbone::new(vb.pp("backbone"), w)?,
        })
    }

    /// The surface features of `s` (computed once per training step or once after training).
    pub fn surface(&self, s: &Tensor) -> Result<SurfaceFeatures> {
        self.surface.forward(s)
    }

    pub fn forward_with(&self, x: &Tensor, s: &SurfaceFeatures) -> Result<Tensor> {
        self.backbone.forward(x, s)
    }

    pub fn forward(&self, x: &Tensor, s: &Tensor) -> Result<Tensor> {
        let f = self.surface(s)?;
        self.forward_with(x, &f)
    }
}

/// Multiply-accumulates of one backbone pass (the simplified network's per-frame work) on an
/// `h`×`w` input with base width `c`, counted layer by layer from [`Backbone`]'s layers:
/// 3.22 GMAC at 256² and the paper's width.
pub fn backbone_macs(h: usize, w: usize, c: usize) -> f64 {
    let full = (h * w) as f64;
    let (half, quarter) = (full / 4.0, full / 16.0);
    let c = c as f64;
    let conv = |pixels: f64, cin: f64, cout: f64, k: f64| pixels * cin * cout * k * k;
    3.0 * conv(full, 3.0, 3.0, 3.0) // skip1
        + conv(half, 3.0, c, 3.0) // conv1 (stride 2)
        + conv(half, c, 2.0 * c, 1.0) // skip2
        + conv(quarter, c, 2.0 * c, 3.0) // conv2 (stride 2)
        + conv(quarter, 2.0 * c, 4.0 * c, 1.0) // skip3
        + conv(quarter, 2.0 * c, 4.0 * c, 3.0) // conv3
        + conv(quarter, 4.0 * c, 8.0 * c, 3.0) // conv4
        + conv(quarter, 8.0 * c, 4.0 * c, 3.0) // conv5
        + conv(quarter, 4.0 * c, 2.0 * c, 2.0) // tconv1 (2×2 per input pixel)
        + conv(half, 2.0 * c, c, 2.0) // tconv2
        + conv(full, c, 3.0, 3.0) // conv6
}

/// Multiply-accumulates of one surface-branch pass on an `h`×`w` input with base width `c`.
pub fn surface_macs(h: usize, w: usize, c: usize) -> f64 {
    let full = (h * w) as f64;
    let (half, quarter) = (full / 4.0, full / 16.0);
    let c = c as f64;
    half * 3.0 * c * 9.0 + quarter * (c * 2.0 * c + 2.0 * c * 4.0 * c + 4.0 * c * 8.0 * c) * 9.0
}
