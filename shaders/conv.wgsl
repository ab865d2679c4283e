// Convolution layers of the simplified CompenNet backbone (CompenNet++ family), one pipeline per
// kernel kind (`conv`, `conv_tiled`, `tconv`, `tconv_tiled`) shared by every layer; per-layer
// sizes come from the uniform. `conv` and `conv_tiled` compute the same thing, as do `tconv` and
// `tconv_tiled`: the direct kernels suit CPU drivers (lavapipe), the tiled ones GPUs
// (src/gpu/context.rs, `ConvKernels`).
//
// Activations: f32 storage buffers, one image per channel, channel-major (C, H, W) row-major,
// network-space pixels at the layer's resolution (the network size, /2 or /4). Values are whatever
// the layer computes (the backbone's input is the sampled desired view, sRGB-encoded camera
// values in [0,1]; its output the projector input values in [0,1]).
// Weights: repacked on the CPU as [ci][ky][kx][co] with co padded to a multiple of 4·B, read as
// vec4 (4 output channels); bias likewise (co padded).
// CPU reference: compend::nn::compennet::Backbone::forward (candle conv2d / conv_transpose2d,
// PyTorch semantics, dilation 1, no output padding), then `+ add`, ReLU, `min(., 1)` as flagged.
//
// In the direct kernels, each invocation computes 4·B output channels (B vec4 accumulators; B is
// a pipeline constant, 1 for layers with few output channels) of one output pixel (`tconv`) or
// of P consecutive output pixels of a row (`conv`): x, y = output pixel (or group of P), z =
// output channel block. A workgroup is 8×8 pixels of one channel block, so its weight reads are
// the same for every invocation (broadcast), and each input value read serves 4·B multiply-adds.
// The tiled kernels are described at `conv_tiled`.

struct Conv {
    cin: u32,             // input channels
    cout: u32,            // output channels
    k: u32,               // kernel size (square)
    stride: u32,
    in_size: vec2<u32>,   // input (width, height)
    out_size: vec2<u32>,  // output (width, height)
    pad: u32,             // zero padding (conv), cropping (tconv), pixels
    flags: u32,           // 1: add the `add` map; 2: ReLU; 4: min(., 1) after the ReLU
    cout4: u32,           // vec4s per weight row: ceil(cout / (4·B))·B
    _pad: u32,
}

// vec4 accumulators per invocation, 1..=MAXB.
override B: u32 = 1u;
const MAXB: u32 = 4u;

const ADD: u32 = 1u;
const RELU: u32 = 2u;
const CLAMP1: u32 = 4u;

@group(0) @binding(0) var<uniform> p: Conv;
@group(0) @binding(1) var<storage, read> src: array<f32>;
@group(0) @binding(2) var<storage, read> weight: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> bias: array<vec4<f32>>;
// Same shape as dst (a surface-bias map or a skip activation); a 1-element dummy when unused.
@group(0) @binding(4) var<storage, read> add: array<f32>;
@group(0) @binding(5) var<storage, read_write> dst: array<f32>;

// Adds the map, activates and stores output channels co0..co0+3 (those below `cout`) of output
// pixel `pix` (row-major index in the output plane); `v` holds their pre-activations, bias
// included.
fn store4(v: vec4<f32>, co0: u32, pix: u32) {
    let plane = p.out_size.x * p.out_size.y;
    for (var j = 0u; j < 4u; j++) {
        let co = co0 + j;
        if (co >= p.cout) {
            break;
        }
        let o = co * plane + pix;
        var x = v[j];
        if ((p.flags & ADD) != 0u) {
            x += add[o];
        }
        if ((p.flags & RELU) != 0u) {
            x = max(x, 0.0);
        }
        if ((p.flags & CLAMP1) != 0u) {
            x = min(x, 1.0);
        }
        dst[o] = x;
    }
}

// Bias already in `acc`; stores the 4·B channels of block id.z at output pixel id.xy.
fn finish(acc: ptr<function, array<vec4<f32>, MAXB>>, id: vec3<u32>) {
    let pix = id.y * p.out_size.x + id.x;
    for (var j = 0u; j < B; j++) {
        store4((*acc)[j], (id.z * B + j) * 4u, pix);
    }
}

// out[co, oy, ox] = b[co] + Σ_ci Σ_ky,kx src[ci, oy·s + ky − pad, ox·s + kx − pad]
// · w[co, ci, ky, kx] (zero outside the input). Each invocation computes P consecutive output
// pixels of a row (x = gid.x·P + i) for its 4·B channels: per input value read, 4·B
// multiply-adds; per weight read, P.
// Reads are branch-free (clamped index, zero weight outside) so that all lanes stay converged.
const P: u32 = 4u;

@compute @workgroup_size(8, 8, 1)
fn conv(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(workgroup_id) wg: vec3<u32>) {
    // The channel block from the workgroup id: uniform over the workgroup (weight reads are the
    // same for all its invocations).
    let ox0 = gid.x * P;
    if (ox0 >= p.out_size.x || gid.y >= p.out_size.y || wg.z * B >= p.cout4) {
        return;
    }
    let zb = wg.z * B; // first vec4 of this invocation's channels
    var acc: array<array<vec4<f32>, MAXB>, P>;
    for (var j = 0u; j < B; j++) {
        let b = bias[zb + j];
        for (var i = 0u; i < P; i++) {
            acc[i][j] = b;
        }
    }
    let w_in = i32(p.in_size.x);
    let h_in = i32(p.in_size.y);
    let plane = p.in_size.x * p.in_size.y;
    let k = i32(p.k);
    let s = i32(p.stride);
    let y0 = i32(gid.y) * s - i32(p.pad);
    let x0 = i32(ox0) * s - i32(p.pad);
    var v: array<f32, P>;
    for (var ci = 0u; ci < p.cin; ci++) {
        let base = ci * plane;
        let wbase = ci * p.k * p.k;
        for (var ky = 0; ky < k; ky++) {
            let iy = y0 + ky;
            let row_ok = iy >= 0 && iy < h_in;
            let row = base + u32(clamp(iy, 0, h_in - 1) * w_in);
            let wrow = (wbase + u32(ky) * p.k) * p.cout4 + zb;
            for (var kx = 0; kx < k; kx++) {
                for (var i = 0u; i < P; i++) {
                    let ix = x0 + i32(i) * s + kx;
                    let ok = row_ok && ix >= 0 && ix < w_in;
                    v[i] = select(0.0, src[row + u32(clamp(ix, 0, w_in - 1))], ok);
                }
                let wi = wrow + u32(kx) * p.cout4;
                for (var j = 0u; j < B; j++) {
                    let wv = weight[wi + j];
                    for (var i = 0u; i < P; i++) {
                        acc[i][j] += v[i] * wv;
                    }
                }
            }
        }
    }
    for (var i = 0u; i < P; i++) {
        let ox = ox0 + i;
        if (ox < p.out_size.x) {
            var a = acc[i];
            finish(&a, vec3<u32>(ox, gid.y, wg.z));
        }
    }
}

// Transposed convolution: out[co, oy, ox] = b[co] + Σ_ci Σ_ky,kx src[ci, iy, ix]
// · w[ci, co, ky, kx] over the input pixels with iy·s + ky − pad = oy and ix·s + kx − pad = ox.
@compute @workgroup_size(8, 8, 1)
fn tconv(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(workgroup_id) wg: vec3<u32>) {
    let id = vec3<u32>(gid.xy, wg.z);
    if (id.x >= p.out_size.x || id.y >= p.out_size.y || id.z * B >= p.cout4) {
        return;
    }
    let zb = id.z * B; // first vec4 of this invocation's channels
    var acc: array<vec4<f32>, MAXB>;
    for (var j = 0u; j < B; j++) {
        acc[j] = bias[zb + j];
    }
    let w_in = i32(p.in_size.x);
    let h_in = i32(p.in_size.y);
    let s = i32(p.stride);
    let plane = p.in_size.x * p.in_size.y;
    let k = i32(p.k);
    let oy = i32(id.y) + i32(p.pad);
    let ox = i32(id.x) + i32(p.pad);
    for (var ky = 0; ky < k; ky++) {
        let ty = oy - ky;
        if (ty < 0 || ty % s != 0 || ty / s >= h_in) {
            continue;
        }
        let iy = ty / s;
        for (var kx = 0; kx < k; kx++) {
            let tx = ox - kx;
            if (tx < 0 || tx % s != 0 || tx / s >= w_in) {
                continue;
            }
            let pix = u32(iy * w_in + tx / s);
            let wk = u32(ky * k + kx);
            for (var ci = 0u; ci < p.cin; ci++) {
                let v = src[ci * plane + pix];
                let wi = (ci * p.k * p.k + wk) * p.cout4 + zb;
                for (var j = 0u; j < B; j++) {
                    acc[j] += v * weight[wi + j];
                }
            }
        }
    }
    finish(&acc, id);
}

// The same convolution as `conv`, as a tiled matrix product (implicit GEMM) for GPUs, whose
// many cores `conv` leaves idle on the backbone's small, wide layers (64×64 pixels × 256
// channels gives `conv` 16 384 invocations, each a long serial sum).
//
// out (M pixels × N channels) = A (M × K) · W (K × N), K = cin·k·k in the order (ci, ky, kx)
// (the weights' packed row order), A[m, (ci, ky, kx)] = the input value under tap (ky, kx) of
// output pixel m (zero outside the input). A workgroup of 16×16 invocations computes a tile of
// TM = 64 output pixels × 64 output channels (16 vec4s of the padded channels): it stages
// TK = 16 rows of K at a time in workgroup memory (each invocation loads 4 values of A and one
// vec4 of W), then each invocation adds them into its 4 pixels (lid.x + 16·i) × 4 channels
// (vec4 lid.y). Per staged value, 16 (A) or 64 (W) multiply-adds. The sum runs over K in the
// same order as `conv`'s, bias first. Pixels of the tile past the output and channel vec4s past
// cout4 compute what their guarded reads give (the bias, zeros) and are not stored.
// Dispatch: (ceil(M / 64), ceil(cout4 / 16), 1).
const TM: u32 = 64u;
const TN4: u32 = 16u;
const TK: u32 = 16u;

var<workgroup> tile_a: array<f32, 1024>;       // [TK][TM]
var<workgroup> tile_w: array<vec4<f32>, 256>;  // [TK][TN4]

@compute @workgroup_size(16, 16, 1)
fn conv_tiled(
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(workgroup_id) wg: vec3<u32>,
) {
    let t = lid.y * 16u + lid.x;
    let plane_out = p.out_size.x * p.out_size.y;
    let plane_in = p.in_size.x * p.in_size.y;
    let kk = p.k * p.k;
    let kdim = p.cin * kk;
    let w_in = i32(p.in_size.x);
    let h_in = i32(p.in_size.y);
    let s = i32(p.stride);
    let last_src = arrayLength(&src) - 1u;
    let last_w = arrayLength(&weight) - 1u;

    // This invocation's channel vec4, its bias in each accumulator.
    let n4 = wg.y * TN4 + lid.y;
    let n_ok = n4 < p.cout4;
    var acc = tile_bias(n4);

    // The pixel whose A values this invocation stages (column t % TM, rows t / TM + 4·r).
    let mc = t % TM;
    let m = wg.x * TM + mc;
    let m_ok = m < plane_out;
    let oy = i32(m / max(p.out_size.x, 1u));
    let ox = i32(m % max(p.out_size.x, 1u));
    let iy0 = oy * s - i32(p.pad);
    let ix0 = ox * s - i32(p.pad);
    // The W vec4 it stages: row t / TN4, column t % TN4 of the tile.
    let wn4 = wg.y * TN4 + t % TN4;

    for (var k0 = 0u; k0 < kdim; k0 += TK) {
        for (var r = 0u; r < 4u; r++) {
            let row = t / TM + 4u * r;
            let kq = k0 + row;
            let ci = kq / kk;
            let tap = kq % kk;
            let iy = iy0 + i32(tap / p.k);
            let ix = ix0 + i32(tap % p.k);
            let ok = m_ok && kq < kdim && iy >= 0 && iy < h_in && ix >= 0 && ix < w_in;
            let idx = ci * plane_in + u32(clamp(iy, 0, h_in - 1) * w_in + clamp(ix, 0, w_in - 1));
            tile_a[row * TM + mc] = select(0.0, src[min(idx, last_src)], ok);
        }
        let kw = k0 + t / TN4;
        let w_ok = kw < kdim && wn4 < p.cout4;
        tile_w[t] = select(vec4<f32>(0.0), weight[min(kw * p.cout4 + wn4, last_w)], w_ok);
        workgroupBarrier();
        add_tile(&acc, lid.xy);
        workgroupBarrier();
    }

    if (!n_ok) {
        return;
    }
    for (var i = 0u; i < 4u; i++) {
        let mi = wg.x * TM + lid.x + 16u * i;
        if (mi < plane_out) {
            store4(acc[i], n4 * 4u, mi);
        }
    }
}

// The bias of channel vec4 `n4` (zero past cout4) in each of a tiled invocation's 4
// accumulators.
fn tile_bias(n4: u32) -> array<vec4<f32>, 4> {
    let b = select(vec4<f32>(0.0), bias[min(n4, arrayLength(&bias) - 1u)], n4 < p.cout4);
    return array<vec4<f32>, 4>(b, b, b, b);
}

// Adds the staged tile (TK rows of K) into the accumulators of invocation `l` (local id): its
// pixels l.x + 16·i (i = 0..3) of the tile × its channel vec4 l.y, in the order of K.
fn add_tile(acc: ptr<function, array<vec4<f32>, 4>>, l: vec2<u32>) {
    for (var q = 0u; q < TK; q++) {
        let wv = tile_w[q * TN4 + l.y];
        for (var i = 0u; i < 4u; i++) {
            (*acc)[i] += tile_a[q * TM + l.x + 16u * i] * wv;
        }
    }
}

// The transposed convolution `tconv` for a kernel as wide as its stride (k = s, as the
// backbone's 2×2 stride-2 layers: each output pixel lies under exactly one tap of one input
// pixel), as k·k matrix products, one per tap (ty, tx) = (z / k, z % k) of the workgroup id z.
// For input pixel m = (iy, ix): out[co, iy·s + ty − pad, ix·s + tx − pad] = b[co] +
// Σ_ci src[ci, m] · w[ci, co, ty, tx], i.e. (M input pixels × N channels) = A (M × cin) · W_tap
// (cin × N) with A[m, ci] = src[ci, m]. The same tiles as `conv_tiled` (K = cin), the sum over
// ci in `tconv`'s order, bias first; output pixels past the crop are not stored.
// Dispatch: (ceil(input pixels / 64), ceil(cout4 / 16), k·k).
@compute @workgroup_size(16, 16, 1)
fn tconv_tiled(
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(workgroup_id) wg: vec3<u32>,
) {
    let t = lid.y * 16u + lid.x;
    let plane_in = p.in_size.x * p.in_size.y;
    let tap = wg.z;
    let last_src = arrayLength(&src) - 1u;
    let last_w = arrayLength(&weight) - 1u;

    // This invocation's channel vec4, its bias in each accumulator.
    let n4 = wg.y * TN4 + lid.y;
    let n_ok = n4 < p.cout4;
    var acc = tile_bias(n4);

    // The input pixel whose values this invocation stages (column t % TM, rows t / TM + 4·r),
    // and the W vec4 (row t / TN4, column t % TN4 of the tile).
    let mc = t % TM;
    let m = wg.x * TM + mc;
    let m_ok = m < plane_in;
    let wn4 = wg.y * TN4 + t % TN4;

    for (var k0 = 0u; k0 < p.cin; k0 += TK) {
        for (var r = 0u; r < 4u; r++) {
            let row = t / TM + 4u * r;
            let ci = k0 + row;
            let ok = m_ok && ci < p.cin;
            tile_a[row * TM + mc] = select(0.0, src[min(ci * plane_in + m, last_src)], ok);
        }
        let cw = k0 + t / TN4;
        let w_ok = cw < p.cin && wn4 < p.cout4;
        let wi = (cw * p.k * p.k + tap) * p.cout4 + wn4;
        tile_w[t] = select(vec4<f32>(0.0), weight[min(wi, last_w)], w_ok);
        workgroupBarrier();
        add_tile(&acc, lid.xy);
        workgroupBarrier();
    }

    if (!n_ok) {
        return;
    }
    let w_in = max(p.in_size.x, 1u);
    let s = i32(p.stride);
    let ty = i32(tap / max(p.k, 1u)) - i32(p.pad);
    let tx = i32(tap % max(p.k, 1u)) - i32(p.pad);
    for (var i = 0u; i < 4u; i++) {
        let mi = wg.x * TM + lid.x + 16u * i;
        let oy = i32(mi / w_in) * s + ty;
        let ox = i32(mi % w_in) * s + tx;
        let inside = oy >= 0 && ox >= 0 && oy < i32(p.out_size.y) && ox < i32(p.out_size.x);
        if (mi < plane_in && inside) {
            store4(acc[i], n4 * 4u, u32(oy) * p.out_size.x + u32(ox));
        }
    }
}
