//! The CompenNet++ family's photometric stage on the GPU: the simplified CompenNet backbone
//! (DESIGN.md 5.2–5.3) as a chain of compute dispatches.
//!
//! 1. `sample` (`shaders/compennet.wgsl`): the desired camera view (rgba32float texture, camera
//!    pixels, sRGB-encoded camera values, FOV-masked) sampled through the baked grid into the
//!    backbone input, a (3, H, W) f32 storage buffer in network pixels;
//! 2. the backbone's 13 convolutions and transposed convolutions (`shaders/conv.wgsl`), each with
//!    its bias, the constant surface-bias map s1..s4 or skip activation added, ReLU, and the final
//!    `min(., 1)`; activations are (C, h, w) f32 storage buffers at the layer's resolution;
//! 3. `store`: the output (projector input values in [0,1]) into the compensation image
//!    (rgba32float storage texture, network pixels).
//!
//! Everything is built once per model: weights repacked and uploaded, activation buffers
//! allocated, one uniform buffer and bind group per layer. Per frame: only dispatches (one
//! pipeline per kernel kind, reused by every layer). f32 throughout.
//! CPU reference: [`crate::nn::train::SimplifiedCompenNet::forward`].

use bytemuck::{Pod, Zeroable};
use candle_core::Tensor;

use super::GpuContext;
use super::kernel::{Slot, Stage, scratch, storage, uniform};
use crate::error::{Error, Result};
use crate::nn::train::SimplifiedCompenNet;

const SHADER: &str = include_str!("../../shaders/compennet.wgsl");
const CONV: &str = include_str!("../../shaders/conv.wgsl");

/// Output channels per vec4 accumulator of the convolution kernels.
const LANES: usize = 4;
/// vec4 accumulators per invocation (the shader's `B`) for layers with at least
/// `4 * WIDE_BLOCK` output channels; 1 for the others (the 3-channel layers).
const WIDE_BLOCK: usize = 4;
/// Workgroup of the convolution kernels: 8×8 invocations of one channel block.
const WG: u32 = 8;
/// Output pixels per invocation along x of the `conv` kernel (the shader's `P`).
const PIXELS: u32 = 4;

const FLAG_ADD: u32 = 1;
const FLAG_RELU: u32 = 2;
const FLAG_CLAMP1: u32 = 4;

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct NetParams {
    camera: [u32; 2],
    network: [u32; 2],
    half: [f32; 2],
    _pad: [f32; 2],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable, Debug)]
struct ConvParams {
    cin: u32,
    cout: u32,
    k: u32,
    stride: u32,
    in_size: [u32; 2],
    out_size: [u32; 2],
    pad: u32,
    flags: u32,
    cout4: u32,
    _pad: u32,
}

/// An activation: a (channels, height, width) f32 storage buffer.
struct Act {
    buffer: wgpu::Buffer,
    channels: usize,
    size: (usize, usize),
}

/// One recorded layer: which kernel, its bind group, its workgroup counts.
struct Layer {
    name: &'static str,
    /// Index into [`CompenNetStage::kernels`].
    kernel: usize,
    group: wgpu::BindGroup,
    groups: (u32, u32, u32),
}

/// The simplified CompenNet backbone on the GPU, for one model (fixed network size).
pub struct CompenNetStage {
    sample: Stage,
    store: Stage,
    /// One pipeline per kernel kind: (transposed, vec4 accumulators per invocation).
    kernels: Vec<((bool, usize), Stage)>,
    params: wgpu::Buffer,
    grid: wgpu::Buffer,
    input: Act,
    output: Act,
    layers: Vec<Layer>,
    /// Activations by layer name, kept for read-back in tests.
    acts: Vec<(&'static str, Act)>,
    network_size: (u32, u32),
}

/// A tensor's values as f32, row-major.
fn values(t: &Tensor, what: &str) -> Result<Vec<f32>> {
    t.to_dtype(candle_core::DType::F32)
        .and_then(|t| t.flatten_all())
        .and_then(|t| t.to_vec1::<f32>())
        .map_err(|e| Error::Failed(format!("CompenNet on the GPU: reading {what}: {e}")))
}

/// A layer's weights as plain data: `w[co][ci][ky][kx]` (conv layout) whatever the kind.
struct Weights {
    cin: usize,
    cout: usize,
    k: usize,
    stride: usize,
    pad: usize,
    transposed: bool,
    /// (cout, cin, k, k).
    w: Vec<f32>,
    bias: Vec<f32>,
}

impl Weights {
    fn conv(c: &candle_nn::Conv2d, name: &str) -> Result<Self> {
        let cfg = c.config();
        if cfg.dilation != 1 || cfg.groups != 1 {
            return Err(Error::Input(format!(
                "CompenNet layer {name}: dilation {} / groups {} (the GPU pass has 1 / 1)",
                cfg.dilation, cfg.groups
            )));
        }
        let (cout, cin, k, k2) = c
            .weight()
            .dims4()
            .map_err(|e| Error::Shape(format!("CompenNet layer {name}: {e}")))?;
        if k != k2 {
            return Err(Error::Shape(format!(
                "CompenNet layer {name}: non-square kernel {k}x{k2}"
            )));
        }
        let w = values(c.weight(), name)?;
        let bias = match c.bias() {
            Some(b) => values(b, name)?,
            None => vec![0.0; cout],
        };
        Ok(Self {
            cin,
            cout,
            k,
            stride: cfg.stride,
            pad: cfg.padding,
            transposed: false,
            w,
            bias,
        })
    }

    fn tconv(c: &candle_nn::ConvTranspose2d, name: &str) -> Result<Self> {
        let cfg = c.config();
        if cfg.dilation != 1 || cfg.output_padding != 0 {
            return Err(Error::Input(format!(
                "CompenNet layer {name}: dilation {} / output padding {} (the GPU pass has 1 / 0)",
                cfg.dilation, cfg.output_padding
            )));
        }
        // candle's transposed-convolution weight is (cin, cout, k, k).
        let (cin, cout, k, k2) = c
            .weight()
            .dims4()
            .map_err(|e| Error::Shape(format!("CompenNet layer {name}: {e}")))?;
        if k != k2 {
            return Err(Error::Shape(format!(
                "CompenNet layer {name}: non-square kernel {k}x{k2}"
            )));
        }
        let src = values(c.weight(), name)?;
        let mut w = vec![0.0; src.len()];
        for ci in 0..cin {
            for co in 0..cout {
                for t in 0..k * k {
                    w[(co * cin + ci) * k * k + t] = src[(ci * cout + co) * k * k + t];
                }
            }
        }
        let bias = match c.bias() {
            Some(b) => values(b, name)?,
            None => vec![0.0; cout],
        };
        Ok(Self {
            cin,
            cout,
            k,
            stride: cfg.stride,
            pad: cfg.padding,
            transposed: true,
            w,
            bias,
        })
    }

    /// Output size (width, height) for an input of `(w, h)`.
    fn out_size(&self, (w, h): (usize, usize), name: &str) -> Result<(usize, usize)> {
        let (k, s, p) = (self.k, self.stride.max(1), self.pad);
        let size = |n: usize| -> Option<usize> {
            if self.transposed {
                ((n.checked_sub(1)?) * s + k).checked_sub(2 * p)
            } else {
                Some((n + 2 * p).checked_sub(k)? / s + 1)
            }
        };
        match (size(w), size(h)) {
            (Some(a), Some(b)) if a > 0 && b > 0 => Ok((a, b)),
            _ => Err(Error::Shape(format!(
                "CompenNet layer {name}: no output for a {w}x{h} input"
            ))),
        }
    }

    /// vec4 accumulators per invocation for this layer.
    fn block(&self) -> usize {
        if self.cout >= LANES * WIDE_BLOCK {
            WIDE_BLOCK
        } else {
            1
        }
    }

    /// Padded output channels: a multiple of 4 · [`Self::block`].
    fn cout_padded(&self) -> usize {
        let n = LANES * self.block();
        self.cout.div_ceil(n) * n
    }

    /// Weights as `[ci][ky][kx][co]`, co padded to [`Self::cout_padded`]; bias padded likewise.
    fn packed(&self) -> (Vec<f32>, Vec<f32>) {
        let cp = self.cout_padded();
        let kk = self.k * self.k;
        let mut w = vec![0.0; self.cin * kk * cp];
        for co in 0..self.cout {
            for ci in 0..self.cin {
                for t in 0..kk {
                    w[(ci * kk + t) * cp + co] = self.w[(co * self.cin + ci) * kk + t];
                }
            }
        }
        let mut b = vec![0.0; cp];
        b[..self.cout].copy_from_slice(&self.bias);
        (w, b)
    }
}

/// What is added to a layer's pre-activation.
enum Add<'a> {
    None,
    /// A constant map (the folded surface branch), uploaded once.
    Constant(&'a Tensor),
    /// An earlier activation (a skip connection), by name.
    Skip(&'static str),
}

impl CompenNetStage {
    /// Uploads the grid (network pixels → normalised camera positions), the backbone's weights
    /// and the surface-bias maps once, and allocates the activations; `camera_size` is the desired
    /// view's size in camera pixels.
    pub fn new(
        ctx: &GpuContext,
        model: &SimplifiedCompenNet,
        camera_size: (usize, usize),
    ) -> Result<Self> {
        let shape = |e: candle_core::Error| Error::Shape(format!("CompenNet on the GPU: {e}"));
        let (_, nh, nw, two) = model.grid.dims4().map_err(shape)?;
        if two != 2 || nw % 4 != 0 || nh % 4 != 0 {
            return Err(Error::Shape(format!(
                "CompenNet on the GPU: grid {:?} is not (1, H, W, 2) with H and W divisible by 4",
                model.grid.dims()
            )));
        }
        let (cw, ch) = camera_size;
        let slots = [
            Slot::Uniform,
            Slot::Texture,
            Slot::Storage,
            Slot::StorageRw,
            Slot::Output(wgpu::TextureFormat::Rgba32Float),
        ];
        let sample = Stage::new(ctx, "compennet sample", SHADER, "sample", &slots)?;
        let store = Stage::new(ctx, "compennet store", SHADER, "store", &slots)?;
        let conv_slots = [
            Slot::Uniform,
            Slot::Storage,
            Slot::Storage,
            Slot::Storage,
            Slot::Storage,
            Slot::StorageRw,
        ];
        let mut kernels: Vec<((bool, usize), Stage)> = Vec::new();
        let half = |n: usize| (n.max(1) - 1) as f32 / 2.0;
        let params = uniform(
            ctx,
            "compennet params",
            &NetParams {
                camera: [cw as u32, ch as u32],
                network: [nw as u32, nh as u32],
                // (n − 1)/2 in f32, as compend::nn::grid_sample computes it.
                half: [half(cw), half(ch)],
                _pad: [0.0; 2],
            },
        );
        let grid = storage(ctx, "compennet grid", &values(&model.grid, "the grid")?);
        let limit = ctx.device.limits().max_storage_buffer_binding_size as usize;
        let alloc = |label: &str, channels: usize, size: (usize, usize)| -> Result<Act> {
            let bytes = 4 * channels * size.0 * size.1;
            if bytes > limit {
                return Err(Error::Input(format!(
                    "CompenNet on the GPU: activation {label} ({channels}x{}x{}) needs {bytes} \
                     bytes, more than this device's storage binding limit of {limit} (use a \
                     smaller network size)",
                    size.1, size.0
                )));
            }
            Ok(Act {
                buffer: scratch(ctx, label, channels * size.0 * size.1),
                channels,
                size,
            })
        };
        let input = alloc("x", 3, (nw, nh))?;
        let b = &model.backbone;
        let s = &model.bias;
        // The forward pass of compend::nn::compennet::Backbone, layer by layer:
        // (name, weights, input, add, flags).
        let plan: Vec<(&'static str, Weights, &'static str, Add, u32)> = vec![
            (
                "skip1.0",
                Weights::conv(&b.skip1.convs[0], "skip1.0")?,
                "x",
                Add::None,
                FLAG_RELU,
            ),
            (
                "skip1.1",
                Weights::conv(&b.skip1.convs[1], "skip1.1")?,
                "skip1.0",
                Add::None,
                FLAG_RELU,
            ),
            (
                "res1",
                Weights::conv(&b.skip1.convs[2], "skip1.2")?,
                "skip1.1",
                Add::None,
                FLAG_RELU,
            ),
            (
                "a1",
                Weights::conv(&b.conv1, "conv1")?,
                "x",
                Add::Constant(&s.s1),
                FLAG_ADD | FLAG_RELU,
            ),
            (
                "res2",
                Weights::conv(&b.skip2, "skip2")?,
                "a1",
                Add::None,
                0,
            ),
            (
                "a2",
                Weights::conv(&b.conv2, "conv2")?,
                "a1",
                Add::Constant(&s.s2),
                FLAG_ADD | FLAG_RELU,
            ),
            (
                "res3",
                Weights::conv(&b.skip3, "skip3")?,
                "a2",
                Add::None,
                0,
            ),
            (
                "a3",
                Weights::conv(&b.conv3, "conv3")?,
                "a2",
                Add::Constant(&s.s3),
                FLAG_ADD | FLAG_RELU,
            ),
            (
                "a4",
                Weights::conv(&b.conv4, "conv4")?,
                "a3",
                Add::Constant(&s.s4),
                FLAG_ADD | FLAG_RELU,
            ),
            (
                "a5",
                Weights::conv(&b.conv5, "conv5")?,
                "a4",
                Add::Skip("res3"),
                FLAG_ADD | FLAG_RELU,
            ),
            (
                "a6",
                Weights::tconv(&b.tconv1, "tconv1")?,
                "a5",
                Add::Skip("res2"),
                FLAG_ADD | FLAG_RELU,
            ),
            (
                "a7",
                Weights::tconv(&b.tconv2, "tconv2")?,
                "a6",
                Add::None,
                FLAG_RELU,
            ),
            (
                "out",
                Weights::conv(&b.conv6, "conv6")?,
                "a7",
                Add::Skip("res1"),
                FLAG_ADD | FLAG_RELU | FLAG_CLAMP1,
            ),
        ];
        let dummy = storage(ctx, "no add", &[0.0]);
        let mut acts: Vec<(&'static str, Act)> = Vec::new();
        let mut layers = Vec::new();
        for (name, w, from, add, flags) in plan {
            let find = |acts: &[(&'static str, Act)], n: &str| -> Result<usize> {
                acts.iter()
                    .position(|(a, _)| *a == n)
                    .ok_or_else(|| Error::Failed(format!("CompenNet plan: no activation {n}")))
            };
            let src = if from == "x" {
                &input
            } else {
                &acts[find(&acts, from)?].1
            };
            if src.channels != w.cin {
                return Err(Error::Shape(format!(
                    "CompenNet layer {name}: {} input channels, the weights take {}",
                    src.channels, w.cin
                )));
            }
            let out_size = w.out_size(src.size, name)?;
            let dst = alloc(name, w.cout, out_size)?;
            let n_out = w.cout * out_size.0 * out_size.1;
            let constant;
            let add_buffer = match add {
                Add::None => &dummy,
                Add::Constant(t) => {
                    let v = values(t, name)?;
                    if v.len() != n_out {
                        return Err(Error::Shape(format!(
                            "CompenNet layer {name}: surface-bias map {:?}, the layer's output is \
                             ({}, {}, {})",
                            t.dims(),
                            w.cout,
                            out_size.1,
                            out_size.0
                        )));
                    }
                    constant = storage(ctx, name, &v);
                    &constant
                }
                Add::Skip(n) => {
                    let a = &acts[find(&acts, n)?].1;
                    if (a.channels, a.size) != (w.cout, out_size) {
                        return Err(Error::Shape(format!(
                            "CompenNet layer {name}: skip {n} is {}x{}x{}, the output {}x{}x{}",
                            a.channels, a.size.1, a.size.0, w.cout, out_size.1, out_size.0
                        )));
                    }
                    &a.buffer
                }
            };
            let (wp, bp) = w.packed();
            let block = w.block();
            let cout4 = (w.cout_padded() / LANES) as u32;
            let p = ConvParams {
                cin: w.cin as u32,
                cout: w.cout as u32,
                k: w.k as u32,
                stride: w.stride as u32,
                in_size: [src.size.0 as u32, src.size.1 as u32],
                out_size: [out_size.0 as u32, out_size.1 as u32],
                pad: w.pad as u32,
                flags,
                cout4,
                _pad: 0,
            };
            let key = (w.transposed, block);
            let kernel = match kernels.iter().position(|(k, _)| *k == key) {
                Some(i) => i,
                None => {
                    let entry = if w.transposed { "tconv" } else { "conv" };
                    let label = format!("{entry} x{}", LANES * block);
                    kernels.push((
                        key,
                        Stage::with_constants(
                            ctx,
                            &label,
                            CONV,
                            entry,
                            &conv_slots,
                            &[("B", block as f64)],
                        )?,
                    ));
                    kernels.len() - 1
                }
            };
            let group = kernels[kernel].1.bind(
                ctx,
                name,
                &[
                    uniform(ctx, name, &p).as_entire_binding(),
                    src.buffer.as_entire_binding(),
                    storage(ctx, name, &wp).as_entire_binding(),
                    storage(ctx, name, &bp).as_entire_binding(),
                    add_buffer.as_entire_binding(),
                    dst.buffer.as_entire_binding(),
                ],
            );
            layers.push(Layer {
                name,
                kernel,
                group,
                groups: (
                    (out_size.0 as u32)
                        .div_ceil(if w.transposed { 1 } else { PIXELS })
                        .div_ceil(WG),
                    (out_size.1 as u32).div_ceil(WG),
                    cout4 / block as u32,
                ),
            });
            acts.push((name, dst));
        }
        let output = acts
            .pop()
            .map(|(_, a)| a)
            .ok_or_else(|| Error::Failed("CompenNet plan: no layers".into()))?;
        if (output.channels, output.size) != (3, (nw, nh)) {
            return Err(Error::Shape(format!(
                "CompenNet on the GPU: the backbone's output is {}x{}x{}, the network {}x{}x3",
                output.channels, output.size.1, output.size.0, nh, nw
            )));
        }
        Ok(Self {
            sample,
            store,
            kernels,
            params,
            grid,
            input,
            output,
            layers,
            acts,
            network_size: (nw as u32, nh as u32),
        })
    }

    /// The bind groups reading the desired view `desired` and writing the network image
    /// `network`: [sample, store].
    pub fn bind(
        &self,
        ctx: &GpuContext,
        desired: &wgpu::TextureView,
        network: &wgpu::TextureView,
    ) -> Vec<wgpu::BindGroup> {
        [(&self.sample, &self.input), (&self.store, &self.output)]
            .into_iter()
            .map(|(stage, act)| {
                stage.bind(
                    ctx,
                    "compennet",
                    &[
                        self.params.as_entire_binding(),
                        wgpu::BindingResource::TextureView(desired),
                        self.grid.as_entire_binding(),
                        act.buffer.as_entire_binding(),
                        wgpu::BindingResource::TextureView(network),
                    ],
                )
            })
            .collect()
    }

    /// Records the whole backbone: sample, the layers in order, store.
    pub fn dispatch(&self, pass: &mut wgpu::ComputePass<'_>, groups: &[wgpu::BindGroup]) {
        let [sample, store] = groups else {
            // bind() always returns two groups; nothing to record otherwise.
            return;
        };
        self.sample.dispatch(pass, sample, self.network_size);
        for l in &self.layers {
            if let Some((_, stage)) = self.kernels.get(l.kernel) {
                stage.dispatch_groups(pass, &l.group, l.groups);
            }
        }
        self.store.dispatch(pass, store, self.network_size);
    }

    /// Records layer `i` alone (in [`Self::layer_names`] order), reading the activations the
    /// last frame left: for per-layer timing.
    pub fn dispatch_layer(&self, pass: &mut wgpu::ComputePass<'_>, i: usize) {
        if let Some(l) = self.layers.get(i)
            && let Some((_, stage)) = self.kernels.get(l.kernel)
        {
            stage.dispatch_groups(pass, &l.group, l.groups);
        }
    }

    /// Names of the intermediate activations in order ("x" is the sampled input; the output is
    /// the compensation image).
    pub fn layer_names(&self) -> Vec<&'static str> {
        self.layers.iter().map(|l| l.name).collect()
    }

    /// An activation read back as (channels, height, width, values (C, H, W) row-major), for tests:
    /// `x` the sampled input, a layer's name its output (see [`Self::layer_names`]).
    pub fn read_activation(
        &self,
        ctx: &GpuContext,
        name: &str,
    ) -> Result<(usize, usize, usize, Vec<f32>)> {
        let act = match name {
            "x" => &self.input,
            "out" => &self.output,
            _ => self
                .acts
                .iter()
                .find(|(n, _)| *n == name)
                .map(|(_, a)| a)
                .ok_or_else(|| Error::Input(format!("no CompenNet activation `{name}`")))?,
        };
        let v = ctx.read_buffer(&act.buffer)?;
        Ok((act.channels, act.size.1, act.size.0, v))
    }
}
