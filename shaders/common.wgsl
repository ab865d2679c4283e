// Functions shared by the compensation shaders (compiled in front of each: `shaders/linear.wgsl`,
// `shaders/joint.wgsl`). They read the module's `p.camera` (the camera frame's size) and its
// `desired` texture (the desired view, camera pixels, sRGB-encoded camera values).

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

// A 3×3 matrix as its rows; `ok` false where it has no inverse.
struct Rows {
    r: array<vec3<f32>, 3>,
    ok: bool,
}

// M⁻¹ by cofactors; not ok when |det| <= 1e-6 · the product of the row norms, or not finite
// (compend::linear::gamut::inverse).
fn inverse3(m: array<vec3<f32>, 3>) -> Rows {
    var out: Rows;
    let c00 = m[1].y * m[2].z - m[1].z * m[2].y;
    let c01 = m[1].z * m[2].x - m[1].x * m[2].z;
    let c02 = m[1].x * m[2].y - m[1].y * m[2].x;
    let det = m[0].x * c00 + m[0].y * c01 + m[0].z * c02;
    let scale = length(m[0]) * length(m[1]) * length(m[2]);
    // NaN fails every comparison; infinity fails the second.
    out.ok = abs(det) > 1e-6 * scale && abs(det) <= 3.4e38;
    if (!out.ok) {
        return out;
    }
    let r = 1.0 / det;
    out.r[0] = vec3<f32>(
        c00 * r,
        (m[0].z * m[2].y - m[0].y * m[2].z) * r,
        (m[0].y * m[1].z - m[0].z * m[1].y) * r,
    );
    out.r[1] = vec3<f32>(
        c01 * r,
        (m[0].x * m[2].z - m[0].z * m[2].x) * r,
        (m[0].z * m[1].x - m[0].x * m[1].z) * r,
    );
    out.r[2] = vec3<f32>(
        c02 * r,
        (m[0].y * m[2].x - m[0].x * m[2].y) * r,
        (m[0].x * m[1].y - m[0].y * m[1].x) * r,
    );
    return out;
}

