// Stage 1 of the compensation pass: content frame -> desired camera-view image z'.
//
// Input:  the content frame, 8-bit sRGB-encoded RGBA (rgba8unorm, so textureLoad returns v/255
//         exactly), content pixels.
// Output: z' in camera pixels, f32 (rgba32float), still sRGB-encoded camera values (no
//         linearisation here): the content mapped into the display range, stretched into the
//         displayable area with bilinear resizing (half-pixel centres, clamped to the edge
//         pixels: compend::resize), its edge pixels repeated `margin` camera pixels outward,
//         black beyond that and outside the model's FOV mask.
// CPU reference: compend::playback::desired_view followed by Rgb::masked (Model::infer).

struct Place {
    camera: vec2<u32>,      // camera frame size, camera pixels
    content: vec2<u32>,     // content frame size, content pixels
    area_origin: vec2<u32>, // displayable area, camera pixels
    area_size: vec2<u32>,
    range: vec2<f32>,       // display range: low, high (camera values in [0,1])
    margin: u32,            // camera pixels the area's edge is repeated outward
    _pad: u32,
}

@group(0) @binding(0) var<uniform> p: Place;
@group(0) @binding(1) var content: texture_2d<f32>;
// FOV mask, camera pixels, row-major: 1 inside, 0 outside.
@group(0) @binding(2) var<storage, read> fov: array<f32>;
@group(0) @binding(3) var desired: texture_storage_2d<rgba32float, write>;

// Half-pixel bilinear tap of output index i on an axis resized from n_src to n_dst pixels:
// (lower index, upper index, weight of the upper one), as compend::resize::bilinear_taps.
fn taps(i: u32, n_src: u32, n_dst: u32) -> vec3<f32> {
    let scale = f32(n_src) / f32(n_dst);
    let s = clamp((f32(i) + 0.5) * scale - 0.5, 0.0, f32(n_src - 1u));
    let i0 = floor(s);
    let i1 = min(i0 + 1.0, f32(n_src - 1u));
    return vec3<f32>(i0, i1, s - i0);
}

fn ranged(x: u32, y: u32) -> vec3<f32> {
    let v = textureLoad(content, vec2<u32>(x, y), 0).rgb;
    return p.range.x + (p.range.y - p.range.x) * v;
}

@compute @workgroup_size(8, 8)
fn place(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x >= p.camera.x || id.y >= p.camera.y) {
        return;
    }
    var out = vec3<f32>(0.0);
    // Signed position in the area; within `margin` outside it, the nearest edge pixel.
    let pos = vec2<i32>(id.xy) - vec2<i32>(p.area_origin);
    let size = vec2<i32>(p.area_size);
    let m = i32(p.margin);
    let near = pos.x >= -m && pos.y >= -m && pos.x < size.x + m && pos.y < size.y + m;
    if (near && fov[id.y * p.camera.x + id.x] > 0.5) {
        let at = vec2<u32>(clamp(pos, vec2<i32>(0), size - vec2<i32>(1)));
        let tx = taps(at.x, p.content.x, p.area_size.x);
        let ty = taps(at.y, p.content.y, p.area_size.y);
        let x0 = u32(tx.x);
        let x1 = u32(tx.y);
        let y0 = u32(ty.x);
        let y1 = u32(ty.y);
        // Horizontal first, then vertical, as the CPU's separable resize.
        let h0 = (1.0 - tx.z) * ranged(x0, y0) + tx.z * ranged(x1, y0);
        let h1 = (1.0 - tx.z) * ranged(x0, y1) + tx.z * ranged(x1, y1);
        out = (1.0 - ty.z) * h0 + ty.z * h1;
    }
    textureStore(desired, vec2<u32>(id.xy), vec4<f32>(out, 1.0));
}
