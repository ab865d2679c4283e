// Stage 2 of the compensation pass for the `linear` model: desired camera view z' -> network-space
// compensation image.
//
// Input:  z' (rgba32float), camera pixels, sRGB-encoded camera values.
// Grid:   per network pixel, the camera position to sample in normalised coordinates [-1, 1],
//         align_corners = true (-1/+1 = centres of the first/last camera pixels).
// Output: the projector input values (sRGB-encoded like the PNGs the model was trained on), f32
//         (rgba32float), network pixels.
// Maths (compend::linear::SimplifiedLinear::apply): bilinear sample of z' at the grid position,
// zero outside; per channel, linearise with the camera curve a = max(v, 0)^γc; linear projector
// light l = M a + b (3×3 + offset per network pixel); projector input clamp(l, 0, 1)^(1/γp).
// Everything in f32 with textureLoad, no texture-unit filtering (it is not exact).

struct Linear {
    camera: vec2<u32>,  // camera frame size
    network: vec2<u32>, // network size
    camera_gamma: vec4<f32>,        // γc per channel (xyz)
    projector_inv_gamma: vec4<f32>, // 1/γp per channel (xyz), computed in f32 on the CPU
}

@group(0) @binding(0) var<uniform> p: Linear;
@group(0) @binding(1) var desired: texture_2d<f32>;
@group(0) @binding(2) var<storage, read> grid: array<vec2<f32>>;
// 12 values per network pixel: M row-major (9), then b (3).
@group(0) @binding(3) var<storage, read> coeffs: array<f32>;
@group(0) @binding(4) var network: texture_storage_2d<rgba32float, write>;

// Bilinear sample at normalised position g, zero outside (compend::sample::for_each_tap).
fn grid_sample(g: vec2<f32>) -> vec3<f32> {
    let w = p.camera.x;
    let h = p.camera.y;
    let u = (g.x + 1.0) * 0.5 * f32(w - 1u);
    let v = (g.y + 1.0) * 0.5 * f32(h - 1u);
    var acc = vec3<f32>(0.0);
    // Also rejects NaN (every comparison is false).
    if (!(u > -1.0 && u < f32(w) && v > -1.0 && v < f32(h))) {
        return acc;
    }
    let x0 = floor(u);
    let y0 = floor(v);
    let fx = u - x0;
    let fy = v - y0;
    let ix = i32(x0);
    let iy = i32(y0);
    for (var dy = 0; dy < 2; dy++) {
        let yy = iy + dy;
        let wy = select(1.0 - fy, fy, dy == 1);
        if (yy < 0 || yy >= i32(h) || wy == 0.0) {
            continue;
        }
        for (var dx = 0; dx < 2; dx++) {
            let xx = ix + dx;
            let wx = select(1.0 - fx, fx, dx == 1);
            if (xx < 0 || xx >= i32(w) || wx == 0.0) {
                continue;
            }
            let wt = wx * wy;
            acc += wt * textureLoad(desired, vec2<i32>(xx, yy), 0).rgb;
        }
    }
    return acc;
}

// x^g for x > 0, else 0 (Rust's powf(0, g) = 0 for g > 0; WGSL's pow(0, g) is not defined).
fn pow0(x: f32, g: f32) -> f32 {
    return select(0.0, pow(x, g), x > 0.0);
}

@compute @workgroup_size(8, 8)
fn linear(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x >= p.network.x || id.y >= p.network.y) {
        return;
    }
    let i = id.y * p.network.x + id.x;
    let s = grid_sample(grid[i]);
    let a = vec3<f32>(
        pow0(s.x, p.camera_gamma.x),
        pow0(s.y, p.camera_gamma.y),
        pow0(s.z, p.camera_gamma.z),
    );
    let k = i * 12u;
    var out = vec3<f32>(0.0);
    for (var c = 0u; c < 3u; c++) {
        let l = coeffs[k + c * 3u] * a.x + coeffs[k + c * 3u + 1u] * a.y
            + coeffs[k + c * 3u + 2u] * a.z + coeffs[k + 9u + c];
        out[c] = pow0(clamp(l, 0.0, 1.0), p.projector_inv_gamma[c]);
    }
    textureStore(network, vec2<u32>(id.xy), vec4<f32>(out, 1.0));
}
