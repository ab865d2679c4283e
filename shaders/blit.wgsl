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
