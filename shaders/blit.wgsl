// Presents the projector frame on the window's surface: one fullscreen triangle, each fragment
// copies the texel under it (textureLoad, no filtering): the surface gets the frame's exact bytes
// when the surface is as large as the frame (a non-sRGB surface format: no re-encoding).

@group(0) @binding(0) var frame: texture_2d<f32>;

@vertex
fn vs(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    let x = f32((i << 1u) & 2u) * 2.0 - 1.0;
    let y = f32(i & 2u) * 2.0 - 1.0;
    return vec4<f32>(x, y, 0.0, 1.0);
}

@fragment
fn fs(@builtin(position) pos: vec4<f32>) -> @location(0) vec4<f32> {
    let size = textureDimensions(frame);
    let xy = vec2<u32>(pos.xy);
    if (xy.x >= size.x || xy.y >= size.y) {
        return vec4<f32>(0.0, 0.0, 0.0, 1.0);
    }
    return textureLoad(frame, xy, 0);
}

// A set's projector image (its network lattice, projector input values) stretched over the whole
// surface: bilinear with half-pixel centres, the source coordinate of surface pixel x being
// (x + 0.5) · frame / surface − 0.5, clamped to the first and last texel centres. CPU reference:
// `resize::resize_bilinear` (src/resize.rs). Equal sizes copy each texel exactly.
@group(0) @binding(1) var<uniform> surface: vec4<f32>;

@fragment
fn fs_stretch(@builtin(position) pos: vec4<f32>) -> @location(0) vec4<f32> {
    let size = vec2<i32>(textureDimensions(frame));
    let last = vec2<f32>(size - vec2<i32>(1, 1));
    let s = clamp(pos.xy * vec2<f32>(size) / surface.xy - 0.5, vec2<f32>(0.0), last);
    let i0 = vec2<i32>(floor(s));
    let i1 = min(i0 + vec2<i32>(1, 1), size - vec2<i32>(1, 1));
    let f = s - floor(s);
    let a = mix(textureLoad(frame, i0, 0), textureLoad(frame, vec2<i32>(i1.x, i0.y), 0), f.x);
    let b = mix(textureLoad(frame, vec2<i32>(i0.x, i1.y), 0), textureLoad(frame, i1, 0), f.x);
    return vec4<f32>(clamp(mix(a, b, f.y).rgb, vec3<f32>(0.0), vec3<f32>(1.0)), 1.0);
}
