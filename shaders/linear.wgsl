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
// light l = M a + b (3×3 + offset per network pixel); where l leaves [0, 1]³, the reachable light
// closest in camera-encoded values (compend::linear::gamut, same steps in the same order);
// projector input l^(1/γp).
// Everything in f32 with textureLoad, no texture-unit filtering (it is not exact). Compiled after
// shaders/common.wgsl (grid_sample, pow0, inverse3).

struct Linear {
    camera: vec2<u32>,  // camera frame size
    network: vec2<u32>, // network size
    camera_gamma: vec4<f32>,        // γc per channel (xyz)
    camera_inv_gamma: vec4<f32>,    // 1/γc per channel (xyz), computed in f32 on the CPU
    projector_inv_gamma: vec4<f32>, // 1/γp per channel (xyz), computed in f32 on the CPU
}

@group(0) @binding(0) var<uniform> p: Linear;
@group(0) @binding(1) var desired: texture_2d<f32>;
@group(0) @binding(2) var<storage, read> grid: array<vec2<f32>>;
// 12 values per network pixel: M row-major (9), then b (3).
@group(0) @binding(3) var<storage, read> coeffs: array<f32>;
@group(0) @binding(4) var network: texture_storage_2d<rgba32float, write>;

// (W A)ᵀ (W A) for W = diag(w).
fn weighted_gram(a: array<vec3<f32>, 3>, w: vec3<f32>) -> array<vec3<f32>, 3> {
    var q: array<vec3<f32>, 3>;
    for (var i = 0u; i < 3u; i++) {
        for (var j = 0u; j < 3u; j++) {
            var s = 0.0;
            for (var r = 0u; r < 3u; r++) {
                s += w[r] * w[r] * a[r][i] * a[r][j];
            }
            q[i][j] = s;
        }
    }
    return q;
}

struct Solution {
    x: vec3<f32>,
    ok: bool,
}

// The point of one assignment (per coordinate: 0 free, 1 held at 0, 2 held at 1): the held
// coordinates at their bounds, the free ones from the stationarity equations, whether or not
// that lands in [0, 1]; not ok when they are singular (compend::linear::gamut::solve).
fn solve(q_in: array<vec3<f32>, 3>, u: vec3<f32>, state_in: vec3<u32>) -> Solution {
    var q = q_in;
    var state = state_in;
    var out: Solution;
    out.ok = false;
    var x = u;
    var nfree = 0u;
    var free = vec2<u32>(0u, 0u);
    for (var c = 0u; c < 3u; c++) {
        if (state[c] == 1u) {
            x[c] = 0.0;
        } else if (state[c] == 2u) {
            x[c] = 1.0;
        } else {
            if (nfree < 2u) {
                free[nfree] = c;
            }
            nfree += 1u;
        }
    }
    // −Q_fc (x_c − u_c) for every row.
    var r = vec3<f32>(0.0);
    for (var i = 0u; i < 3u; i++) {
        var acc = 0.0;
        for (var c = 0u; c < 3u; c++) {
            if (state[c] != 0u) {
                acc += q[i][c] * (x[c] - u[c]);
            }
        }
        r[i] = -acc;
    }
    if (nfree == 1u) {
        let i = free.x;
        if (q[i][i] <= 0.0) {
            return out;
        }
        x[i] = u[i] + r[i] / q[i][i];
    } else if (nfree == 2u) {
        let i = free.x;
        let j = free.y;
        let det = q[i][i] * q[j][j] - q[i][j] * q[j][i];
        if (det <= 0.0) {
            return out;
        }
        x[i] = u[i] + (r[i] * q[j][j] - q[i][j] * r[j]) / det;
        x[j] = u[j] + (q[i][i] * r[j] - q[j][i] * r[i]) / det;
    }
    out.ok = true;
    out.x = x;
    return out;
}

// Inside [0, 1]³; NaN is not (compend::linear::gamut::feasible).
fn feasible(x: vec3<f32>) -> bool {
    return all(x >= vec3<f32>(0.0)) && all(x <= vec3<f32>(1.0));
}

// The gradient Q (x − u), one coordinate.
fn gradient(q: array<vec3<f32>, 3>, d: vec3<f32>, c: u32) -> f32 {
    var row = q;
    return row[c].x * d.x + row[c].y * d.y + row[c].z * d.z;
}

// The optimality conditions at a feasible point of an assignment: the gradient Q (x − u) pushes
// every held coordinate against its bound (compend::linear::gamut::optimal).
fn optimal(q: array<vec3<f32>, 3>, u: vec3<f32>, x: vec3<f32>, state_in: vec3<u32>) -> bool {
    var state = state_in;
    let d = x - u;
    for (var c = 0u; c < 3u; c++) {
        let g = gradient(q, d, c);
        if ((state[c] == 1u && !(g >= 0.0)) || (state[c] == 2u && !(g <= 0.0))) {
            return false;
        }
    }
    return true;
}

// The active-set step: hold each free coordinate outside [0, 1] at the bound it crossed, free
// each held one whose gradient points into the box (compend::linear::gamut::next_state).
fn next_state(q: array<vec3<f32>, 3>, u: vec3<f32>, x: vec3<f32>, state_in: vec3<u32>) -> vec3<u32> {
    var state = state_in;
    var xs = x;
    var next = state;
    let d = x - u;
    for (var c = 0u; c < 3u; c++) {
        let g = gradient(q, d, c);
        if (state[c] == 1u) {
            if (g < 0.0) {
                next[c] = 0u;
            }
        } else if (state[c] == 2u) {
            if (g > 0.0) {
                next[c] = 0u;
            }
        } else if (xs[c] < 0.0) {
            next[c] = 1u;
        } else if (xs[c] > 1.0) {
            next[c] = 2u;
        }
    }
    return next;
}

// The assignment clamping u suggests (compend::linear::gamut::clamp_state).
fn clamp_state(u: vec3<f32>) -> vec3<u32> {
    return select(select(vec3<u32>(0u), vec3<u32>(2u), u > vec3<f32>(1.0)), vec3<u32>(1u), u < vec3<f32>(0.0));
}

struct BoxSolution {
    x: vec3<f32>,
    state: vec3<u32>,
    ok: bool,
}

// argmin over x in [0, 1]³ of (x − u)ᵀ Q (x − u) from assignment `start`: at most 4 active-set
// steps; where they do not settle on the minimum, every assignment, the feasible point of least
// cost (compend::linear::gamut::box_least_squares_from).
fn box_least_squares(q: array<vec3<f32>, 3>, u: vec3<f32>, start: vec3<u32>) -> BoxSolution {
    var out: BoxSolution;
    out.ok = false;
    var state = start;
    for (var step = 0u; step < 4u; step++) {
        let s = solve(q, u, state);
        if (!s.ok) {
            break;
        }
        let next = next_state(q, u, s.x, state);
        if (all(next == state)) {
            if (feasible(s.x) && optimal(q, u, s.x, state)) {
                out.x = s.x;
                out.state = state;
                out.ok = true;
                return out;
            }
            break;
        }
        state = next;
    }
    var best_cost = 0.0;
    for (var k = 0u; k < 27u; k++) {
        let st = vec3<u32>(k % 3u, (k / 3u) % 3u, k / 9u);
        let cand = solve(q, u, st);
        if (!cand.ok || !feasible(cand.x)) {
            continue;
        }
        let d = cand.x - u;
        var cost = 0.0;
        for (var i = 0u; i < 3u; i++) {
            cost += d[i] * gradient(q, d, i);
        }
        if (!out.ok || cost < best_cost) {
            out.x = cand.x;
            out.state = st;
            out.ok = true;
            best_cost = cost;
        }
    }
    return out;
}

// The projector linear light for a desired colour whose model output l is out of [0, 1]³, z the
// desired camera value (compend::linear::gamut::nearest_reachable).
fn nearest_reachable(m: array<vec3<f32>, 3>, l: vec3<f32>, z: vec3<f32>) -> vec3<f32> {
    let clamped = clamp(l, vec3<f32>(0.0), vec3<f32>(1.0));
    let inv = inverse3(m);
    if (!inv.ok) {
        return clamped;
    }
    let a = inv.r;
    var first = clamped;
    var state = clamp_state(l);
    let s1 = box_least_squares(weighted_gram(a, vec3<f32>(1.0)), l, state);
    if (s1.ok) {
        first = s1.x;
        state = s1.state;
    }
    let d = first - l;
    var w = vec3<f32>(0.0);
    for (var c = 0u; c < 3u; c++) {
        let inv_g = p.camera_inv_gamma[c];
        let a0 = pow0(z[c], p.camera_gamma[c]);
        let a1 = a0 + a[c].x * d.x + a[c].y * d.y + a[c].z * d.z;
        if (abs(a1 - a0) > 1e-6) {
            w[c] = (pow0(clamp(a1, 0.0, 1.0), inv_g) - pow0(clamp(a0, 0.0, 1.0), inv_g)) / (a1 - a0);
        } else {
            w[c] = inv_g * pow(max(a0, 1e-4), inv_g - 1.0);
        }
        w[c] = max(w[c], 0.02);
    }
    // The weights move the minimum a little: its assignment usually stays.
    let s2 = box_least_squares(weighted_gram(a, w), l, state);
    if (s2.ok) {
        return s2.x;
    }
    return first;
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
    var m: array<vec3<f32>, 3>;
    var l = vec3<f32>(0.0);
    for (var c = 0u; c < 3u; c++) {
        m[c] = vec3<f32>(coeffs[k + c * 3u], coeffs[k + c * 3u + 1u], coeffs[k + c * 3u + 2u]);
        l[c] = m[c].x * a.x + m[c].y * a.y + m[c].z * a.z + coeffs[k + 9u + c];
    }
    if (any(l < vec3<f32>(0.0)) || any(l > vec3<f32>(1.0))) {
        l = nearest_reachable(m, l, s);
    }
    var out = vec3<f32>(0.0);
    for (var c = 0u; c < 3u; c++) {
        out[c] = pow0(clamp(l[c], 0.0, 1.0), p.projector_inv_gamma[c]);
    }
    textureStore(network, vec2<u32>(id.xy), vec4<f32>(out, 1.0));
}
