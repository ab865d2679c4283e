// Stage 3 of the compensation pass: network-space compensation image -> projector frame.
//
// Input:  the compensation image (rgba32float), network pixels, projector input values.
// Output: the projector frame at the display's native resolution (rgba8unorm: the store rounds to
//         the nearest 8-bit level and clamps), projector pixels; the compensation image stretched
//         over the canvas with bilinear resizing (half-pixel centres), black elsewhere.
// CPU reference: compend::rig::place_on_canvas.

struct Canvas {
    projector: vec2<u32>, // projector frame size
    network: vec2<u32>,   // network size
    origin: vec2<u32>,    // canvas, projector pixels
    size: vec2<u32>,
}

@group(0) @binding(0) var<uniform> p: Canvas;
@group(0) @binding(1) var network: texture_2d<f32>;
@group(0) @binding(2) var frame: texture_storage_2d<rgba8unorm, write>;

fn taps(i: u32, n_src: u32, n_dst: u32) -> vec3<f32> {
    let scale = f32(n_src) / f32(n_dst);
    let s = clamp((f32(i) + 0.5) * scale - 0.5, 0.0, f32(n_src - 1u));
    let i0 = floor(s);
    let i1 = min(i0 + 1.0, f32(n_src - 1u));
    return vec3<f32>(i0, i1, s - i0);
}

fn at(x: f32, y: f32) -> vec3<f32> {
    return textureLoad(network, vec2<u32>(u32(x), u32(y)), 0).rgb;
}

@compute @workgroup_size(8, 8)
fn canvas(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x >= p.projector.x || id.y >= p.projector.y) {
        return;
    }
    var out = vec3<f32>(0.0);
    let inside = id.x >= p.origin.x && id.y >= p.origin.y
        && id.x < p.origin.x + p.size.x && id.y < p.origin.y + p.size.y;
    if (inside) {
        let tx = taps(id.x - p.origin.x, p.network.x, p.size.x);
        let ty = taps(id.y - p.origin.y, p.network.y, p.size.y);
        let h0 = (1.0 - tx.z) * at(tx.x, ty.x) + tx.z * at(tx.y, ty.x);
        let h1 = (1.0 - tx.z) * at(tx.x, ty.y) + tx.z * at(tx.y, ty.y);
        out = (1.0 - ty.z) * h0 + ty.z * h1;
    }
    textureStore(frame, vec2<u32>(id.xy), vec4<f32>(out, 1.0));
}
