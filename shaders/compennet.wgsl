// First and last steps of the simplified CompenNet backbone on the GPU (the convolutions are in
// conv.wgsl). One layout for both entry points (each uses part of it).
//
// `sample`: desired camera view z' (rgba32float texture, camera pixels, sRGB-encoded camera values,
//   FOV-masked by the place stage) → backbone input x (storage buffer, (3, H, W) channel-major,
//   network pixels): bilinear sample at the baked grid, align_corners = true (-1/+1 = centres of
//   the first/last camera pixels), zero outside. CPU reference: compend::nn::grid_sample (candle),
//   whose source position u = g·(W−1)/2 + (W−1)/2 this reproduces in f32.
// `store`: backbone output (storage buffer, (3, H, W), projector input values already in [0,1])
//   → the compensation image (rgba32float storage texture, network pixels, alpha 1).

struct Net {
    camera: vec2<u32>,  // camera frame (width, height)
    network: vec2<u32>, // network (width, height)
    half: vec2<f32>,    // ((camera width − 1)/2, (camera height − 1)/2), computed on the CPU
    _pad: vec2<f32>,
}

@group(0) @binding(0) var<uniform> p: Net;
@group(0) @binding(1) var desired: texture_2d<f32>;
@group(0) @binding(2) var<storage, read> grid: array<vec2<f32>>;
@group(0) @binding(3) var<storage, read_write> act: array<f32>;
@group(0) @binding(4) var network: texture_storage_2d<rgba32float, write>;

// Bilinear sample at normalised position g, zero outside: the four corners in candle's order,
// corners outside the frame skipped (weight 0 there).
fn grid_sample(g: vec2<f32>) -> vec3<f32> {
    let w = i32(p.camera.x);
    let h = i32(p.camera.y);
    let u = g.x * p.half.x + p.half.x;
    let v = g.y * p.half.y + p.half.y;
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
        if (yy < 0 || yy >= h) {
            continue;
        }
        for (var dx = 0; dx < 2; dx++) {
            let xx = ix + dx;
            let wx = select(1.0 - fx, fx, dx == 1);
            if (xx < 0 || xx >= w) {
                continue;
            }
            acc += (wx * wy) * textureLoad(desired, vec2<i32>(xx, yy), 0).rgb;
        }
    }
    return acc;
}

@compute @workgroup_size(8, 8)
fn sample(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x >= p.network.x || id.y >= p.network.y) {
        return;
    }
    let plane = p.network.x * p.network.y;
    let i = id.y * p.network.x + id.x;
    let s = grid_sample(grid[i]);
    act[i] = s.x;
    act[plane + i] = s.y;
    act[2u * plane + i] = s.z;
}

@compute @workgroup_size(8, 8)
fn store(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x >= p.network.x || id.y >= p.network.y) {
        return;
    }
    let plane = p.network.x * p.network.y;
    let i = id.y * p.network.x + id.x;
    let v = vec3<f32>(act[i], act[plane + i], act[2u * plane + i]);
    textureStore(network, vec2<u32>(id.xy), vec4<f32>(v, 1.0));
}
