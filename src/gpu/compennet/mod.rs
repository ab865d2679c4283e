//! The CompenNet++ family's photometric stage on the GPU: the simplified CompenNet backbone
//! (docs/architecture.md, "Playback"; the surface branch folded into constant bias maps) as a
//! chain of compute dispatches.
//!
//! 1. `sample` (`shaders/compennet.wgsl`): the desired camera view (rgba32float texture, camera
//!    pixels, sRGB-encoded camera values, FOV-masked) sampled through the baked grid into the
//!    backbone input, a (3, H, W) f32 storage buffer in network pixels;
//! 2. the backbone's 13 convolutions and transposed convolutions (`shaders/conv.wgsl`), each with
//!    its bias, the constant surface-bias map s1..s4 or skip activation added, ReLU, and the final
//!    `min(., 1)`; activations are (C, h, w) f32 storage buffers at the layer's resolution; the
//!    wide layers run as [`super::ConvKernels`] says (the context's choice for its adapter);
//! 3. `store`: the output (projector input values in [0,1]) into the compensation image
//!    (rgba32float storage texture, network pixels).
//!
//! Everything is built once per model: weights repacked and uploaded, activation buffers
//! allocated, one uniform buffer and bind group per layer. Per frame: only dispatches (one
//! pipeline per kernel kind, reused by every layer). f32 throughout.
//! CPU reference: [`crate::nn::compennetpp::SimplifiedCompenNet::forward`].

use bytemuck::{Pod, Zeroable};
use candle_core::Tensor;

use super::GpuContext;
use super::kernel::{Slot, Stage, scratch, storage, uniform};
use super::timing::time_work;
use crate::error::{Error, Result};
use crate::nn::compennetpp::SimplifiedCompenNet;

mod weights;

use crate::raster::ImageSize;
use weights::{Weights, values};

const SHADER: &str = include_str!("../../../shaders/compennet.wgsl");
const CONV: &str = include_str!("../../../shaders/conv.wgsl");

/// Output channels per vec4 accumulator of the convolution kernels.
const LANES: usize = 4;
/// vec4 accumulators per invocation (the shader's `B`) for layers with at least
/// `4 * WIDE_BLOCK` output channels; 1 for the others (the 3-channel layers).
const WIDE_BLOCK: usize = 4;
/// Workgroup of the `conv` and `tconv` kernels: 8×8 invocations of one channel block.
const WG: u32 = 8;
/// Output pixels per invocation along x of the `conv` kernel (the shader's `P`).
const PIXELS: u32 = 4;
/// Tile of the `conv_tiled` and `tconv_tiled` kernels: output (input) pixels (the shader's
/// `TM`) and channel vec4s (`TN4`) per workgroup.
const TILE_PIXELS: u32 = 64;
const TILE_VEC4S: u32 = 16;

/// Rounds of timing per kernel when [`super::ConvKernels::Measured`] chooses, the kernels' order
/// reversed from one round to the next; each round is [`TUNE_WARMUP`] untimed and
/// [`TUNE_FRAMES`] timed dispatches of the layer alone.
const TUNE_ROUNDS: usize = 2;
const TUNE_WARMUP: usize = 2;
const TUNE_FRAMES: usize = 2;

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

/// An activation: a (channels, height, width) f32 storage buffer; `size` is (width, height) in
/// pixels of the layer's resolution.
struct Act {
    buffer: wgpu::Buffer,
    channels: usize,
    size: ImageSize,
}

/// One recorded layer: which kernel, its bind group, its workgroup counts.
struct Layer {
    name: &'static str,
    /// Index into [`CompenNetStage::kernels`].
    kernel: usize,
    group: wgpu::BindGroup,
    groups: (u32, u32, u32),
    /// Where the kernel was chosen by timing: each candidate's entry point and its best time
    /// alone (ms: GPU timestamps where the device has them, else submit to idle).
    timed: Vec<(&'static str, f64)>,
}

/// A way to run one layer: its pipeline (index into [`CompenNetStage::kernels`]), bind group
/// and workgroup counts.
struct Candidate {
    entry: &'static str,
    kernel: usize,
    group: wgpu::BindGroup,
    groups: (u32, u32, u32),
}

/// Key of a convolution pipeline: (entry point, vec4 accumulators per invocation).
type KernelKind = (&'static str, usize);

/// The simplified CompenNet backbone on the GPU, for one model (fixed network size).
pub struct CompenNetStage {
    sample: Stage,
    store: Stage,
    /// One pipeline per kernel kind, reused by every layer of that kind.
    kernels: Vec<(KernelKind, Stage)>,
    params: wgpu::Buffer,
    grid: wgpu::Buffer,
    input: Act,
    output: Act,
    layers: Vec<Layer>,
    /// Activations by layer name, kept for read-back in tests.
    acts: Vec<(&'static str, Act)>,
    /// (width, height) of the network image, network pixels.
    network_size: ImageSize,
}

/// What is added to a layer's pre-activation.
enum Add<'a> {
    None,
    /// A constant map (the folded surface branch), uploaded once.
    Constant(&'a Tensor),
    /// An earlier activation (a skip connection), by name.
    Skip(&'static str),
}

/// One step of the forward pass: layer `name` applies `weights` to the activation `from` ("x" =
/// the sampled input), adds `add`, then applies `flags`.
struct Planned<'a> {
    name: &'static str,
    weights: Weights,
    from: &'static str,
    add: Add<'a>,
    flags: u32,
}

/// The forward pass of `compend::nn::compennet::Backbone`, layer by layer, with the weights read
/// out of candle.
fn plan(model: &SimplifiedCompenNet) -> Result<Vec<Planned<'_>>> {
    let (b, s) = (&model.backbone, &model.bias);
    let step = |name, weights, from, add, flags| Planned {
        name,
        weights,
        from,
        add,
        flags,
    };
    let (conv, tconv) = (Weights::conv, Weights::tconv);
    let relu_add = FLAG_ADD | FLAG_RELU;
    // The residual rung's tail is conv6 alone (a signed correction): no input skip to compute.
    let tail = if b.residual {
        step("out", conv(&b.conv6, "conv6")?, "a7", Add::None, 0)
    } else {
        step(
            "out",
            conv(&b.conv6, "conv6")?,
            "a7",
            Add::Skip("res1"),
            relu_add | FLAG_CLAMP1,
        )
    };
    let skip = if b.residual {
        Vec::new()
    } else {
        vec![
            step(
                "skip1.0",
                conv(&b.skip1.convs[0], "skip1.0")?,
                "x",
                Add::None,
                FLAG_RELU,
            ),
            step(
                "skip1.1",
                conv(&b.skip1.convs[1], "skip1.1")?,
                "skip1.0",
                Add::None,
                FLAG_RELU,
            ),
            step(
                "res1",
                conv(&b.skip1.convs[2], "skip1.2")?,
                "skip1.1",
                Add::None,
                FLAG_RELU,
            ),
        ]
    };
    let mut steps = skip;
    steps.extend([
        step(
            "a1",
            conv(&b.conv1, "conv1")?,
            "x",
            Add::Constant(&s.s1),
            relu_add,
        ),
        step("res2", conv(&b.skip2, "skip2")?, "a1", Add::None, 0),
        step(
            "a2",
            conv(&b.conv2, "conv2")?,
            "a1",
            Add::Constant(&s.s2),
            relu_add,
        ),
        step("res3", conv(&b.skip3, "skip3")?, "a2", Add::None, 0),
        step(
            "a3",
            conv(&b.conv3, "conv3")?,
            "a2",
            Add::Constant(&s.s3),
            relu_add,
        ),
        step(
            "a4",
            conv(&b.conv4, "conv4")?,
            "a3",
            Add::Constant(&s.s4),
            relu_add,
        ),
        step(
            "a5",
            conv(&b.conv5, "conv5")?,
            "a4",
            Add::Skip("res3"),
            relu_add,
        ),
        step(
            "a6",
            tconv(&b.tconv1, "tconv1")?,
            "a5",
            Add::Skip("res2"),
            relu_add,
        ),
        step(
            "a7",
            tconv(&b.tconv2, "tconv2")?,
            "a6",
            Add::None,
            FLAG_RELU,
        ),
        tail,
    ]);
    Ok(steps)
}

/// (width, height) of the network image in network pixels, from the baked grid.
fn network_size(model: &SimplifiedCompenNet) -> Result<ImageSize> {
    let (_, nh, nw, two) = model
        .grid
        .dims4()
        .map_err(|e| Error::Shape(format!("CompenNet on the GPU: {e}")))?;
    if two != 2 || nw % 4 != 0 || nh % 4 != 0 {
        return Err(Error::Shape(format!(
            "CompenNet on the GPU: grid {:?} is not (1, H, W, 2) with H and W divisible by 4",
            model.grid.dims()
        )));
    }
    Ok(ImageSize::new(nw, nh))
}

/// Activation buffers, each within the device's storage binding limit.
fn activation(ctx: &GpuContext, label: &str, channels: usize, size: ImageSize) -> Result<Act> {
    let limit = ctx.device.limits().max_storage_buffer_binding_size as usize;
    let bytes = 4 * channels * size.width * size.height;
    if bytes > limit {
        return Err(Error::Input(format!(
            "CompenNet on the GPU: activation {label} ({channels}x{}x{}) needs {bytes} bytes, \
             more than this device's storage binding limit of {limit} (use a smaller network \
             size)",
            size.height, size.width
        )));
    }
    Ok(Act {
        buffer: scratch(ctx, label, channels * size.width * size.height),
        channels,
        size,
    })
}

/// The backbone's layers as they are built: activations, bind groups, and the convolution
/// pipelines compiled so far.
struct Builder<'c> {
    ctx: &'c GpuContext,
    input: Act,
    acts: Vec<(&'static str, Act)>,
    layers: Vec<Layer>,
    kernels: Vec<(KernelKind, Stage)>,
    /// Bound as the added map of layers that add nothing.
    no_add: wgpu::Buffer,
}

impl<'c> Builder<'c> {
    fn new(ctx: &'c GpuContext, input: Act) -> Self {
        Self {
            ctx,
            input,
            acts: Vec::new(),
            layers: Vec::new(),
            kernels: Vec::new(),
            no_add: storage(ctx, "no add", &[0.0]),
        }
    }

    /// The activation `name` ("x" = the sampled input).
    fn act(&self, name: &str) -> Result<&Act> {
        if name == "x" {
            return Ok(&self.input);
        }
        self.acts
            .iter()
            .find(|(a, _)| *a == name)
            .map(|(_, a)| a)
            .ok_or_else(|| Error::Failed(format!("CompenNet plan: no activation {name}")))
    }

    /// The buffer added to layer `name`'s pre-activation of `cout` channels × `size` pixels.
    fn added(&self, name: &str, add: &Add, cout: usize, size: ImageSize) -> Result<wgpu::Buffer> {
        match add {
            Add::None => Ok(self.no_add.clone()),
            Add::Constant(t) => {
                let v = values(t, name)?;
                if v.len() != cout * size.width * size.height {
                    return Err(Error::Shape(format!(
                        "CompenNet layer {name}: surface-bias map {:?}, the layer's output is \
                         ({cout}, {}, {})",
                        t.dims(),
                        size.height,
                        size.width
                    )));
                }
                Ok(storage(self.ctx, name, &v))
            }
            Add::Skip(n) => {
                let a = self.act(n)?;
                if (a.channels, a.size) != (cout, size) {
                    return Err(Error::Shape(format!(
                        "CompenNet layer {name}: skip {n} is {}x{}x{}, the output {cout}x{}x{}",
                        a.channels, a.size.height, a.size.width, size.height, size.width
                    )));
                }
                Ok(a.buffer.clone())
            }
        }
    }

    /// The entry points `w` may run with: for a wide layer (a convolution, or a transposed one
    /// whose kernel is as wide as its stride and crops nothing, as the backbone's: the case
    /// `tconv_tiled` is tested on) those of the context's [`super::ConvKernels`]; `tconv` or
    /// `conv` for the others.
    fn entries(&self, w: &Weights) -> &'static [&'static str] {
        let tileable = !w.transposed || (w.k == w.stride && w.pad == 0);
        if w.block() == WIDE_BLOCK && tileable {
            self.ctx.conv.wide_entries(w.transposed)
        } else if w.transposed {
            &["tconv"]
        } else {
            &["conv"]
        }
    }

    /// The pipeline of `entry` for `w`'s block, compiled on first use.
    fn kernel(&mut self, w: &Weights, entry: &'static str) -> Result<usize> {
        let block = w.block();
        let key = (entry, block);
        if let Some(i) = self.kernels.iter().position(|(k, _)| *k == key) {
            return Ok(i);
        }
        let label = format!("{entry} x{}", LANES * block);
        let slots = [
            Slot::Uniform,
            Slot::Storage,
            Slot::Storage,
            Slot::Storage,
            Slot::Storage,
            Slot::StorageRw,
        ];
        let stage = Stage::with_constants(
            self.ctx,
            &label,
            CONV,
            entry,
            &slots,
            &[("B", block as f64)],
        )?;
        self.kernels.push((key, stage));
        Ok(self.kernels.len() - 1)
    }

    /// The candidate to keep for layer `name` (its index) and, where there is more than one,
    /// each one's best time alone on this device: each round times the candidates in the
    /// reverse of the last round's order, so a GPU still raising its clock does not favour the
    /// one timed last. The figure is the best round's median. A `shape` (the layer's uniform)
    /// timed before on this device is not timed again: the times first taken for it decide.
    fn fastest(
        &self,
        name: &str,
        shape: [u32; 12],
        candidates: &[Candidate],
    ) -> Result<(usize, Vec<(&'static str, f64)>)> {
        if candidates.len() < 2 {
            return Ok((0, Vec::new()));
        }
        let entries: Vec<&'static str> = candidates.iter().map(|c| c.entry).collect();
        let same =
            |t: &[(&'static str, f64)]| t.iter().map(|(e, _)| *e).eq(entries.iter().copied());
        let cache = || {
            self.ctx
                .conv_timed
                .lock()
                .unwrap_or_else(|e| e.into_inner())
        };
        // Times taken before for this shape on this device, if they were of these candidates.
        let before = cache().get(&shape).filter(|t| same(t)).cloned();
        let timed = match before {
            Some(t) => t,
            None => {
                let mine = self.time_candidates(name, candidates)?;
                // Another pass may have timed the same shape meanwhile: the first times kept
                // decide for every pass, so passes on one device agree.
                let mut shapes = cache();
                let kept = shapes.entry(shape).or_insert_with(|| mine.clone());
                if same(kept) { kept.clone() } else { mine }
            }
        };
        let fastest = timed
            .iter()
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(e, _)| *e);
        let i = candidates
            .iter()
            .position(|c| Some(c.entry) == fastest)
            .unwrap_or(0);
        tracing::debug!(
            "CompenNet layer {name}: {} ms; running {}",
            timed
                .iter()
                .map(|(e, t)| format!("{e} {t:.3}"))
                .collect::<Vec<_>>()
                .join(", "),
            candidates[i].entry
        );
        Ok((i, timed))
    }

    /// Each candidate's best time alone on this device, ms, in order (see [`Self::fastest`]).
    fn time_candidates(
        &self,
        name: &str,
        candidates: &[Candidate],
    ) -> Result<Vec<(&'static str, f64)>> {
        // A software adapter's timestamps do not show its real cost (docs/bench: lavapipe's
        // copies): it is timed by the wall clock.
        let software = self.ctx.adapter.get_info().device_type == wgpu::DeviceType::Cpu;
        let mut best = vec![f64::INFINITY; candidates.len()];
        for round in 0..TUNE_ROUNDS {
            let mut order: Vec<usize> = (0..candidates.len()).collect();
            if round % 2 == 1 {
                order.reverse();
            }
            for i in order {
                let (c, b) = (&candidates[i], &mut best[i]);
                let stage = &self.kernels[c.kernel].1;
                let t = time_work(self.ctx, TUNE_WARMUP, TUNE_FRAMES, |enc| {
                    let mut cp = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                        label: Some(name),
                        timestamp_writes: None,
                    });
                    stage.dispatch_groups(&mut cp, &c.group, c.groups);
                    Ok(())
                })?;
                *b = b.min(if software { t.wall_ms } else { t.best_ms() });
            }
        }
        Ok(candidates.iter().map(|c| c.entry).zip(best).collect())
    }

    /// Allocates the layer's output, uploads its weights and records its bind group (for each
    /// kernel it may run with, keeping the fastest: [`super::ConvKernels`]).
    fn push(&mut self, step: Planned) -> Result<()> {
        let Planned {
            name,
            weights: w,
            from,
            add,
            flags,
        } = step;
        let src = self.act(from)?;
        if src.channels != w.cin {
            return Err(Error::Shape(format!(
                "CompenNet layer {name}: {} input channels, the weights take {}",
                src.channels, w.cin
            )));
        }
        let in_size = src.size;
        let src = src.buffer.clone();
        let out_size = w.out_size(in_size, name)?;
        let dst = activation(self.ctx, name, w.cout, out_size)?;
        let added = self.added(name, &add, w.cout, out_size)?;
        let (wp, bp) = w.packed();
        let block = w.block();
        let cout4 = (w.cout_padded() / LANES) as u32;
        let params = ConvParams {
            cin: w.cin as u32,
            cout: w.cout as u32,
            k: w.k as u32,
            stride: w.stride as u32,
            in_size: [in_size.width as u32, in_size.height as u32],
            out_size: [out_size.width as u32, out_size.height as u32],
            pad: w.pad as u32,
            flags,
            cout4,
            _pad: 0,
        };
        let ctx = self.ctx;
        let params_words = params;
        let params = uniform(ctx, name, &params);
        let (wp, bp) = (storage(ctx, name, &wp), storage(ctx, name, &bp));
        let (ow, oh) = (out_size.width as u32, out_size.height as u32);
        let mut candidates = Vec::new();
        for &entry in self.entries(&w) {
            let kernel = self.kernel(&w, entry)?;
            let group = self.kernels[kernel].1.bind(
                ctx,
                name,
                &[
                    params.as_entire_binding(),
                    src.as_entire_binding(),
                    wp.as_entire_binding(),
                    bp.as_entire_binding(),
                    added.as_entire_binding(),
                    dst.buffer.as_entire_binding(),
                ],
            );
            let groups = match entry {
                "conv_tiled" => (
                    (ow * oh).div_ceil(TILE_PIXELS),
                    cout4.div_ceil(TILE_VEC4S),
                    1,
                ),
                // One matrix product per tap, over the input pixels.
                "tconv_tiled" => (
                    ((in_size.width * in_size.height) as u32).div_ceil(TILE_PIXELS),
                    cout4.div_ceil(TILE_VEC4S),
                    (w.k * w.k) as u32,
                ),
                "conv" => (
                    ow.div_ceil(PIXELS).div_ceil(WG),
                    oh.div_ceil(WG),
                    cout4 / block as u32,
                ),
                _ => (ow.div_ceil(WG), oh.div_ceil(WG), cout4 / block as u32),
            };
            candidates.push(Candidate {
                entry,
                kernel,
                group,
                groups,
            });
        }
        let (best, timed) = self.fastest(name, bytemuck::cast(params_words), &candidates)?;
        let Candidate {
            kernel,
            group,
            groups,
            ..
        } = candidates.swap_remove(best);
        self.layers.push(Layer {
            name,
            kernel,
            group,
            groups,
            timed,
        });
        self.acts.push((name, dst));
        Ok(())
    }
}

impl CompenNetStage {
    /// Uploads the grid (network pixels → normalised camera positions), the backbone's weights
    /// and the surface-bias maps once, and allocates the activations; `camera_size` is the desired
    /// view's (width, height) in camera pixels.
    pub fn new(
        ctx: &GpuContext,
        model: &SimplifiedCompenNet,
        camera_size: ImageSize,
    ) -> Result<Self> {
        let ImageSize {
            width: nw,
            height: nh,
        } = network_size(model)?;
        // The sampling and storing pipelines (the convolutions' are compiled per layer kind).
        let slots = [
            Slot::Uniform,
            Slot::Texture,
            Slot::Storage,
            Slot::StorageRw,
            Slot::Output(wgpu::TextureFormat::Rgba32Float),
        ];
        let sample = Stage::new(ctx, "compennet sample", SHADER, "sample", &slots)?;
        let store = Stage::new(ctx, "compennet store", SHADER, "store", &slots)?;
        // The constants of the sampling stage: sizes and the baked grid.
        let ImageSize {
            width: cw,
            height: ch,
        } = camera_size;
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
        // The layers: activations, weights and bind groups, in forward order.
        let mut built = Builder::new(ctx, activation(ctx, "x", 3, ImageSize::new(nw, nh))?);
        for step in plan(model)? {
            built.push(step)?;
        }
        let Builder {
            input,
            mut acts,
            layers,
            kernels,
            ..
        } = built;
        let output = acts
            .pop()
            .map(|(_, a)| a)
            .ok_or_else(|| Error::Failed("CompenNet plan: no layers".into()))?;
        if (output.channels, output.size) != (3, ImageSize::new(nw, nh)) {
            return Err(Error::Shape(format!(
                "CompenNet on the GPU: the backbone's output is {}x{}x{}, the network {}x{}x3",
                output.channels, output.size.height, output.size.width, nh, nw
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
            network_size: ImageSize::new(nw, nh),
        })
    }

    /// (width, height) of the network image it writes, network pixels.
    pub fn network_size(&self) -> ImageSize {
        self.network_size
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

    /// Each layer's name and the kernel (`shaders/conv.wgsl` entry point) that computes it, in
    /// [`Self::layer_names`] order.
    pub fn layer_kernels(&self) -> Vec<(&'static str, &'static str)> {
        self.layers
            .iter()
            .map(|l| {
                let entry = self.kernels.get(l.kernel).map_or("?", |((e, _), _)| *e);
                (l.name, entry)
            })
            .collect()
    }

    /// For each layer whose kernel was chosen by timing ([`super::ConvKernels::Measured`]): its
    /// name and each candidate kernel's best time alone, ms, in [`Self::layer_names`] order.
    pub fn kernel_timings(&self) -> Vec<(&'static str, Vec<(&'static str, f64)>)> {
        self.layers
            .iter()
            .filter(|l| !l.timed.is_empty())
            .map(|l| (l.name, l.timed.clone()))
            .collect()
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
        Ok((act.channels, act.size.height, act.size.width, v))
    }
}
