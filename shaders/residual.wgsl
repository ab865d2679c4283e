// Last step of the compensation pass for the residual rung (compennet++-res): the `linear`
// model's compensation image plus the network's correction, stretched over it.
//
// Inputs: the linear image (rgba32float, network pixels on the linear model's lattice) and the
//         correction (rgba32float, signed, network pixels of the coarser network over the same
//         canvas).
// Output: clamp(linear + bilinear(correction), 0, 1), on the lattice.
// Maths (compend::model::add_correction): per axis, the lattice pixel i samples the correction
// at s = clamp((i + 0.5) * coarse / lattice - 0.5, 0, coarse - 1) (half-pixel centres, edges
// held), between floor(s) and the next pixel (the last one at the edge).

struct Residual {
    lattice: vec2<u32>, // the linear image's size
    coarse: vec2<u32>,  // the correction's size
}

@group(0) @binding(0) var<uniform> p: Residual;
@group(0) @binding(1) var linear_image: texture_2d<f32>;
@group(0) @binding(2) var correction: texture_2d<f32>;
@group(0) @binding(3) var network: texture_storage_2d<rgba32float, write>;

// One axis: (first index, second index, weight of the second).
fn axis(i: u32, src: u32, dst: u32) -> vec3<f32> {
    let scale = f32(src) / f32(dst);
    let s = clamp((f32(i) + 0.5) * scale - 0.5, 0.0, f32(src - 1u));
    let i0 = floor(s);
    let i1 = min(i0 + 1.0, f32(src - 1u));
    return vec3<f32>(i0, i1, s - i0);
}

@compute @workgroup_size(8, 8)
fn residual(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x >= p.lattice.x || id.y >= p.lattice.y) {
        return;
    }
    let ax = axis(id.x, p.coarse.x, p.lattice.x);
    let ay = axis(id.y, p.coarse.y, p.lattice.y);
    let x0 = u32(ax.x);
    let x1 = u32(ax.y);
    let y0 = u32(ay.x);
    let y1 = u32(ay.y);
    let top = mix(
        textureLoad(correction, vec2<u32>(x0, y0), 0).xyz,
        textureLoad(correction, vec2<u32>(x1, y0), 0).xyz,
        ax.z,
    );
    let bottom = mix(
        textureLoad(correction, vec2<u32>(x0, y1), 0).xyz,
        textureLoad(correction, vec2<u32>(x1, y1), 0).xyz,
        ax.z,
    );
    let r = mix(top, bottom, ay.z);
    let l = textureLoad(linear_image, vec2<u32>(id.xy), 0).xyz;
    textureStore(network, vec2<u32>(id.xy), vec4<f32>(clamp(l + r, vec3<f32>(0.0), vec3<f32>(1.0)), 1.0));
}
