// The joint compensation pass of a set of projectors, for one projector's output: desired camera
// view -> this projector's image, compensated for the surface and for the other projectors'
// light (compend::joint; CPU reference compend::joint::JointModel::apply, the per-point solve
// compend::joint::solve::solve, same steps in the same order).
//
// Input:  the desired view (rgba32float), camera pixels, sRGB-encoded camera values.
// Grid:   per lattice pixel of this projector, the camera position in normalised coordinates
//         [-1, 1], align_corners = true.
// Slots:  per lattice pixel and projector of the set, (lattice x, lattice y, share): where that
//         projector is seen at this pixel's camera point, in its lattice's pixels; x < 0 where it
//         does not reach.
// Coeffs: every projector's per-pixel colour model (M row-major, then b; 12 values), one buffer
//         per projector (`p.lattice[j]`: its lattice's width and height).
// Output: this projector's input values (network lattice pixels), f32 (rgba32float).
// Compiled after shaders/common.wgsl (grid_sample, pow0, inverse3).

struct Joint {
    camera: vec2<u32>,  // camera frame size
    network: vec2<u32>, // this projector's lattice size
    set_size: u32,      // projectors in the set
    own: u32,           // this projector's index in the set
    pad: vec2<u32>,
    camera_gamma: vec4<f32>,        // γc per channel (xyz), this projector's model
    camera_inv_gamma: vec4<f32>,    // 1/γc, computed in f32 on the CPU
    projector_inv_gamma: vec4<f32>, // 1/γp of this projector, computed in f32 on the CPU
    lattice: array<vec4<u32>, 4>,   // per projector: lattice width, height (x, y)
}

@group(0) @binding(0) var<uniform> p: Joint;
@group(0) @binding(1) var desired: texture_2d<f32>;
@group(0) @binding(2) var<storage, read> grid: array<vec2<f32>>;
@group(0) @binding(3) var<storage, read> slots: array<f32>;
// One buffer per projector (a storage binding holds at most 128 MiB: one 1920×1080 lattice).
@group(0) @binding(4) var<storage, read> coeffs0: array<f32>;
@group(0) @binding(5) var<storage, read> coeffs1: array<f32>;
@group(0) @binding(6) var<storage, read> coeffs2: array<f32>;
@group(0) @binding(7) var<storage, read> coeffs3: array<f32>;
@group(0) @binding(8) var network: texture_storage_2d<rgba32float, write>;

const MAXP: u32 = 4u;
const MAXU: u32 = 12u;
// compend::joint::solve::{LAMBDA, MAX_STEPS}; the secant's constants are compend::linear::gamut's.
const LAMBDA: f32 = 0.05;
const MAX_STEPS: u32 = 48u;
const WEIGHT_MIN: f32 = 0.02;
const SECANT_MIN: f32 = 1e-6;
const SLOPE_FLOOR: f32 = 1e-4;

// The terms of this point (projectors that reach it, in set order): coefficients and share.
var<private> tk: array<array<f32, 12>, 4>;
var<private> ts: array<f32, 4>;
// The bounded least squares: B's columns, the start x0, H, g, x, which are held.
var<private> cols: array<vec3<f32>, 12>;
var<private> x0: array<f32, 12>;
var<private> h: array<array<f32, 12>, 12>;
var<private> g: array<f32, 12>;
var<private> x: array<f32, 12>;
var<private> held: array<bool, 12>;
var<private> target_x: array<f32, 12>;
var<private> l: array<array<f32, 12>, 12>;

// Value i of projector j's coefficients.
fn coeff(j: u32, i: u32) -> f32 {
    switch j {
        case 0u: { return coeffs0[i]; }
        case 1u: { return coeffs1[i]; }
        case 2u: { return coeffs2[i]; }
        default: { return coeffs3[i]; }
    }
}

// Coefficients of projector j at lattice position (ax, ay), bilinear between the four lattice
// pixels around it, clamped to the lattice (compend::joint::coefficients_at); into tk[n].
fn load_coeffs(n: u32, j: u32, ax: f32, ay: f32) {
    let w = p.lattice[j].x;
    let hh = p.lattice[j].y;
    let xc = clamp(ax, 0.0, f32(w - 1u));
    let yc = clamp(ay, 0.0, f32(hh - 1u));
    let x0i = u32(floor(xc));
    let y0i = u32(floor(yc));
    let x1i = min(x0i + 1u, w - 1u);
    let y1i = min(y0i + 1u, hh - 1u);
    let fx = xc - f32(x0i);
    let fy = yc - f32(y0i);
    var out: array<f32, 12>;
    for (var c = 0u; c < 12u; c++) {
        out[c] = 0.0;
    }
    var xs = array<u32, 4>(x0i, x1i, x0i, x1i);
    var ys = array<u32, 4>(y0i, y0i, y1i, y1i);
    var ws = array<f32, 4>((1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy);
    for (var t = 0u; t < 4u; t++) {
        let base = (ys[t] * w + xs[t]) * 12u;
        for (var c = 0u; c < 12u; c++) {
            out[c] += ws[t] * coeff(j, base + c);
        }
    }
    tk[n] = out;
}

fn matrix_of(n: u32) -> array<vec3<f32>, 3> {
    let k = tk[n];
    return array<vec3<f32>, 3>(
        vec3<f32>(k[0], k[1], k[2]),
        vec3<f32>(k[3], k[4], k[5]),
        vec3<f32>(k[6], k[7], k[8]),
    );
}

// m · v, each row summed left to right (compend::joint::solve::mul).
fn mul3(m: array<vec3<f32>, 3>, v: vec3<f32>) -> vec3<f32> {
    var mm = m;
    var out: vec3<f32>;
    for (var r = 0u; r < 3u; r++) {
        out[r] = mm[r].x * v.x + mm[r].y * v.y + mm[r].z * v.z;
    }
    return out;
}

// The minimum over the free unknowns with the held ones fixed, by Cholesky, into target_x;
// false where H_FF is not positive definite (compend::joint::solve::free_solution).
fn free_solution(m: u32) -> bool {
    var idx: array<u32, 12>;
    var f = 0u;
    for (var i = 0u; i < m; i++) {
        if (!held[i]) {
            idx[f] = i;
            f += 1u;
        }
    }
    for (var i = 0u; i < MAXU; i++) {
        target_x[i] = x[i];
    }
    if (f == 0u) {
        return true;
    }
    var rhs: array<f32, 12>;
    for (var a = 0u; a < f; a++) {
        let i = idx[a];
        var acc = 0.0;
        for (var j = 0u; j < m; j++) {
            if (held[j]) {
                acc += h[i][j] * x[j];
            }
        }
        rhs[a] = g[i] - acc;
        for (var b = 0u; b <= a; b++) {
            var v = h[i][idx[b]];
            for (var k = 0u; k < b; k++) {
                v -= l[a][k] * l[b][k];
            }
            if (a == b) {
                // NaN and infinity fail too.
                if (!(v > 0.0 && v <= 3.4e38)) {
                    return false;
                }
                l[a][a] = sqrt(v);
            } else {
                l[a][b] = v / l[b][b];
            }
        }
    }
    var y: array<f32, 12>;
    for (var a = 0u; a < f; a++) {
        var v = rhs[a];
        for (var k = 0u; k < a; k++) {
            v -= l[a][k] * y[k];
        }
        y[a] = v / l[a][a];
    }
    for (var a1 = f; a1 > 0u; a1--) {
        let a = a1 - 1u;
        var v = y[a];
        for (var k = a + 1u; k < f; k++) {
            v -= l[k][a] * y[k];
        }
        y[a] = v / l[a][a];
    }
    for (var a = 0u; a < f; a++) {
        target_x[idx[a]] = y[a];
    }
    return true;
}

// The primal active-set method from the feasible x (compend::joint::solve::box_minimum).
fn box_minimum(m: u32) {
    for (var i = 0u; i < m; i++) {
        held[i] = x[i] <= 0.0 || x[i] >= 1.0;
    }
    for (var step_n = 0u; step_n < MAX_STEPS; step_n++) {
        if (!free_solution(m)) {
            return;
        }
        var stride = 1.0;
        var blocking = -1;
        var bound = 0.0;
        for (var i = 0u; i < m; i++) {
            if (held[i]) {
                continue;
            }
            let d = target_x[i] - x[i];
            var limit = 3.4e38;
            if (d < 0.0) {
                limit = x[i] / -d;
            } else if (d > 0.0) {
                limit = (1.0 - x[i]) / d;
            }
            if (limit < stride) {
                stride = limit;
                blocking = i32(i);
                bound = select(1.0, 0.0, d < 0.0);
            }
        }
        for (var i = 0u; i < m; i++) {
            if (!held[i]) {
                x[i] = clamp(x[i] + stride * (target_x[i] - x[i]), 0.0, 1.0);
            }
        }
        if (blocking >= 0) {
            x[u32(blocking)] = bound;
            held[u32(blocking)] = true;
            continue;
        }
        var worst = 0.0;
        var which = -1;
        for (var i = 0u; i < m; i++) {
            if (!held[i]) {
                continue;
            }
            var grad = 0.0;
            for (var j = 0u; j < m; j++) {
                grad += h[i][j] * x[j];
            }
            grad = grad - g[i];
            let inward = select(grad, -grad, x[i] <= 0.0);
            if (inward > worst) {
                worst = inward;
                which = i32(i);
            }
        }
        if (which < 0) {
            return;
        }
        held[u32(which)] = false;
    }
}

// argmin over x in [0, 1]^m of ‖W (B x − r)‖² + λ ‖x − x0‖², from the x set by the caller
// (compend::joint::solve::minimise).
fn minimise(m: u32, r: vec3<f32>, w: vec3<f32>) {
    let w2 = w * w;
    for (var i = 0u; i < m; i++) {
        for (var j = 0u; j < m; j++) {
            h[i][j] = w2.x * cols[i].x * cols[j].x + w2.y * cols[i].y * cols[j].y
                + w2.z * cols[i].z * cols[j].z;
        }
    }
    var diag = 0.0;
    for (var i = 0u; i < m; i++) {
        diag += h[i][i];
    }
    let lambda = max(LAMBDA * (diag / f32(max(m, 1u))), 1e-8);
    for (var i = 0u; i < m; i++) {
        h[i][i] += lambda;
        g[i] = (w2.x * cols[i].x * r.x + w2.y * cols[i].y * r.y + w2.z * cols[i].z * r.z)
            + lambda * x0[i];
    }
    box_minimum(m);
}

// This projector's linear light at the point (compend::joint::solve::solve, its `own` term).
fn solve_own(n: u32, own: u32, z: vec3<f32>) -> vec3<f32> {
    var want: vec3<f32>;
    for (var c = 0u; c < 3u; c++) {
        want[c] = pow0(max(z[c], 0.0), p.camera_gamma[c]);
    }
    let own_inv = inverse3(matrix_of(own));
    if (!own_inv.ok) {
        let k = tk[own];
        let l3 = mul3(matrix_of(own), want) + vec3<f32>(k[9], k[10], k[11]);
        return clamp(l3 * ts[own], vec3<f32>(0.0), vec3<f32>(1.0));
    }
    let kb = tk[own];
    let black = mul3(own_inv.r, vec3<f32>(-kb[9], -kb[10], -kb[11]));
    let r = want - black;
    var in_range = true;
    var light: array<vec3<f32>, 4>;
    for (var j = 0u; j < n; j++) {
        let s = ts[j];
        light[j] = mul3(matrix_of(j), vec3<f32>(s * r.x, s * r.y, s * r.z));
        in_range = in_range && all(light[j] >= vec3<f32>(0.0)) && all(light[j] <= vec3<f32>(1.0));
    }
    if (in_range) {
        return light[own];
    }
    let m = 3u * n;
    for (var u = 0u; u < MAXU; u++) {
        cols[u] = vec3<f32>(0.0);
        x0[u] = 0.0;
    }
    for (var j = 0u; j < n; j++) {
        let a = inverse3(matrix_of(j));
        if (a.ok) {
            for (var c = 0u; c < 3u; c++) {
                cols[3u * j + c] = vec3<f32>(a.r[0][c], a.r[1][c], a.r[2][c]);
                x0[3u * j + c] = light[j][c];
            }
        }
    }
    for (var u = 0u; u < MAXU; u++) {
        x[u] = clamp(x0[u], 0.0, 1.0);
    }
    minimise(m, r, vec3<f32>(1.0));
    // Secant weights between the target and the view of the first solution.
    var view: vec3<f32>;
    for (var c = 0u; c < 3u; c++) {
        var acc = 0.0;
        for (var u = 0u; u < m; u++) {
            acc += cols[u][c] * x[u];
        }
        view[c] = black[c] + acc;
    }
    var w: vec3<f32>;
    for (var c = 0u; c < 3u; c++) {
        let inv_g = p.camera_inv_gamma[c];
        let a0 = want[c];
        let a1 = view[c];
        var slope: f32;
        if (abs(a1 - a0) > SECANT_MIN) {
            slope = (pow0(clamp(a1, 0.0, 1.0), inv_g) - pow0(clamp(a0, 0.0, 1.0), inv_g)) / (a1 - a0);
        } else {
            slope = inv_g * pow(max(a0, SLOPE_FLOOR), inv_g - 1.0);
        }
        w[c] = max(slope, WEIGHT_MIN);
    }
    minimise(m, r, w);
    return vec3<f32>(x[3u * own], x[3u * own + 1u], x[3u * own + 2u]);
}

@compute @workgroup_size(8, 8)
fn joint(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x >= p.network.x || id.y >= p.network.y) {
        return;
    }
    let pix = id.y * p.network.x + id.x;
    let z = grid_sample(grid[pix]);
    var n = 0u;
    var own = MAXP;
    for (var j = 0u; j < p.set_size; j++) {
        let base = (pix * p.set_size + j) * 3u;
        let ax = slots[base];
        if (ax < 0.0) {
            continue;
        }
        if (j == p.own) {
            own = n;
        }
        load_coeffs(n, j, ax, slots[base + 1u]);
        ts[n] = slots[base + 2u];
        n += 1u;
    }
    var out = vec3<f32>(0.0);
    if (own < MAXP) {
        let light = solve_own(n, own, z);
        for (var c = 0u; c < 3u; c++) {
            out[c] = pow0(clamp(light[c], 0.0, 1.0), p.projector_inv_gamma[c]);
        }
    }
    textureStore(network, vec2<i32>(i32(id.x), i32(id.y)), vec4<f32>(out, 1.0));
}
