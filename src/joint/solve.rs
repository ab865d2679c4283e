//! The joint solve at one camera point: how much light each projector that reaches it sends,
//! so that together they give the desired view (module documentation of [`super`] for the
//! formulation). This is the CPU reference of the joint pass; it keeps to operations a shader
//! does, on fixed-size arrays, in a fixed order (a primal active-set method with a bounded
//! number of steps, each a Cholesky solve on the free unknowns).

use crate::linear::gamut::{inverse, secant_weight};

/// The most projectors one camera point can be solved for (unknowns: 3 per projector).
pub const MAX_PROJECTORS: usize = 4;
const MAX_UNKNOWNS: usize = 3 * MAX_PROJECTORS;

/// The most working-set changes of one bounded solve ([`box_minimum`]); each adds or frees
/// one bound, and a solve from the clamped split needs a few.
pub const MAX_STEPS: usize = 4 * MAX_UNKNOWNS;

/// Weight of keeping each projector's light near its share of the split, relative to the mean
/// curvature of the view's error (the mean diagonal of `BᵀW²B`). Two projectors reaching one
/// point see it through nearly the same colour model, so the view alone barely tells their
/// light apart: without this term the solve would push one up and the other down to use the
/// small difference in their cross-talk, a difference their fitted models know only within
/// their noise, and the picture would grain where the split is out of range. At 0.05 a
/// change both projectors can make together (more light where one runs out) is made to about
/// 95 %, and one that plays one against the other is damped.
pub const LAMBDA: f32 = 0.05;

/// One projector that reaches the camera point: its colour model there (`M` row-major, then
/// `b`: projector linear light = M · camera linear light + b, as `linear`'s coefficients) and
/// its share of the view ([`super::blend`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Term {
    pub coeffs: [f32; 12],
    pub share: f32,
}

/// Each projector's linear light at a point, in the order of its terms (unused slots 0).
pub type Light = [[f32; 3]; MAX_PROJECTORS];

/// The projector linear light (in [0, 1]³, one per term, in order) that gives camera-encoded
/// value `z` at this point, or as close as the projectors reach: `own` is the term whose model
/// gives the black level (the room's light and every projector's black, camera linear) and
/// whose camera curve `camera_gamma` linearises `z`. A term whose `M` cannot be inverted sends
/// no light (and, if it is `own`, every term its share alone, clamped). Terms past
/// [`MAX_PROJECTORS`] are left out.
pub fn solve(terms: &[Term], own: usize, z: [f32; 3], camera_gamma: [f32; 3]) -> Light {
    let n = terms.len().min(MAX_PROJECTORS);
    let mut light: Light = [[0.0; 3]; MAX_PROJECTORS];
    let target: [f32; 3] = std::array::from_fn(|c| z[c].max(0.0).powf(camera_gamma[c]));
    // The black level: where every projector shows 0, a = -M⁻¹ b (camera linear).
    let black = match terms.get(own).and_then(|t| inverse(&matrix(&t.coeffs))) {
        Some(a) => {
            let b = &terms[own].coeffs[9..12];
            mul(&a, [-b[0], -b[1], -b[2]])
        }
        None => {
            for j in 0..n {
                let l = affine(&terms[j].coeffs, target);
                light[j] = l.map(|v| (v * terms[j].share).clamp(0.0, 1.0));
            }
            return light;
        }
    };
    let r: [f32; 3] = std::array::from_fn(|c| target[c] - black[c]);
    // The blended split: projector j alone gives its share of the view above black.
    let mut in_range = true;
    for j in 0..n {
        let s = terms[j].share;
        light[j] = mul(&matrix(&terms[j].coeffs), [s * r[0], s * r[1], s * r[2]]);
        in_range &= light[j].iter().all(|v| (0.0..=1.0).contains(v));
    }
    if in_range {
        return light;
    }
    // B = [A_1 … A_n], A_j = M_j⁻¹ (a projector that cannot be inverted adds no column and
    // sends no light).
    let m = 3 * n;
    let mut cols = [[0f32; 3]; MAX_UNKNOWNS];
    let mut x0 = [0f32; MAX_UNKNOWNS];
    for j in 0..n {
        if let Some(a) = inverse(&matrix(&terms[j].coeffs)) {
            for c in 0..3 {
                cols[3 * j + c] = [a[0][c], a[1][c], a[2][c]];
                x0[3 * j + c] = light[j][c];
            }
        }
    }
    let clamped = x0.map(|v| v.clamp(0.0, 1.0));
    let first = minimise(&cols[..m], r, &x0[..m], [1.0; 3], &clamped[..m]);
    // Weight each channel by the camera encoding's secant between the target and the view of
    // the first solution, as `linear::gamut` does for one projector.
    let view: [f32; 3] =
        std::array::from_fn(|c| black[c] + (0..m).map(|u| cols[u][c] * first[u]).sum::<f32>());
    let w: [f32; 3] = std::array::from_fn(|c| secant_weight(target[c], view[c], camera_gamma[c]));
    let x = minimise(&cols[..m], r, &x0[..m], w, &first[..m]);
    for j in 0..n {
        light[j] = [x[3 * j], x[3 * j + 1], x[3 * j + 2]];
    }
    light
}

/// `argmin over x in [0, 1]^m of ‖W (B x − r)‖² + λ ‖x − x0‖²` from the feasible point
/// `from`; `cols` are B's columns (m of them, at most [`MAX_UNKNOWNS`]). The minimum is in the
/// first m entries.
fn minimise(
    cols: &[[f32; 3]],
    r: [f32; 3],
    x0: &[f32],
    w: [f32; 3],
    from: &[f32],
) -> [f32; MAX_UNKNOWNS] {
    let m = cols.len().min(MAX_UNKNOWNS);
    let w2 = w.map(|v| v * v);
    let mut h = [[0f32; MAX_UNKNOWNS]; MAX_UNKNOWNS];
    let mut g = [0f32; MAX_UNKNOWNS];
    for i in 0..m {
        for j in 0..m {
            h[i][j] = (0..3).map(|c| w2[c] * cols[i][c] * cols[j][c]).sum();
        }
    }
    let lambda = regularisation(&h, m);
    for i in 0..m {
        h[i][i] += lambda;
        g[i] = (0..3).map(|c| w2[c] * cols[i][c] * r[c]).sum::<f32>() + lambda * x0[i];
    }
    let mut x = [0f32; MAX_UNKNOWNS];
    x[..m].copy_from_slice(&from[..m]);
    box_minimum(&h, &g, m, &mut x);
    x
}

/// `argmin over x in [0, 1]^m of ½ xᵀ H x − gᵀ x` for a symmetric positive definite `H`, by
/// the primal active-set method from the feasible `x`: the unknowns at a bound start held
/// there; each step solves for the free ones with the held ones fixed, moves as far towards
/// that solution as the bounds allow (holding the unknown that blocks), and once it is
/// reached frees the held unknown whose multiplier says the objective falls inside the box
/// (the most negative), until none does or after [`MAX_STEPS`].
fn box_minimum(
    h: &[[f32; MAX_UNKNOWNS]; MAX_UNKNOWNS],
    g: &[f32; MAX_UNKNOWNS],
    m: usize,
    x: &mut [f32; MAX_UNKNOWNS],
) {
    let mut held = [false; MAX_UNKNOWNS];
    for (h, &v) in held.iter_mut().zip(x.iter()).take(m) {
        *h = v <= 0.0 || v >= 1.0;
    }
    for _ in 0..MAX_STEPS {
        let Some(target) = free_solution(h, g, m, x, &held) else {
            return;
        };
        // The longest step towards the free solution that stays in the box.
        let mut step = 1.0f32;
        let mut blocking = None;
        for i in 0..m {
            if held[i] {
                continue;
            }
            let d = target[i] - x[i];
            let limit = if d < 0.0 {
                x[i] / -d
            } else if d > 0.0 {
                (1.0 - x[i]) / d
            } else {
                f32::INFINITY
            };
            if limit < step {
                step = limit;
                blocking = Some((i, if d < 0.0 { 0.0 } else { 1.0 }));
            }
        }
        for i in 0..m {
            if !held[i] {
                x[i] = (x[i] + step * (target[i] - x[i])).clamp(0.0, 1.0);
            }
        }
        if let Some((i, bound)) = blocking {
            x[i] = bound;
            held[i] = true;
            continue;
        }
        // At the free solution: free the held unknown whose gradient points into the box most.
        let mut worst = (0.0f32, None);
        for i in 0..m {
            if !held[i] {
                continue;
            }
            let grad: f32 = (0..m).map(|j| h[i][j] * x[j]).sum::<f32>() - g[i];
            // Held at 0, the objective falls going up where grad < 0; at 1, going down where > 0.
            let into = if x[i] <= 0.0 { -grad } else { grad };
            if into > worst.0 {
                worst = (into, Some(i));
            }
        }
        match worst.1 {
            Some(i) => held[i] = false,
            None => return,
        }
    }
}

/// The minimum over the free unknowns (not `held`) with the held ones at their values in `x`:
/// `H_FF x_F = g_F − H_FH x_H`, by Cholesky; `None` where `H_FF` is not positive definite.
fn free_solution(
    h: &[[f32; MAX_UNKNOWNS]; MAX_UNKNOWNS],
    g: &[f32; MAX_UNKNOWNS],
    m: usize,
    x: &[f32; MAX_UNKNOWNS],
    held: &[bool; MAX_UNKNOWNS],
) -> Option<[f32; MAX_UNKNOWNS]> {
    let mut idx = [0usize; MAX_UNKNOWNS];
    let mut f = 0;
    for (i, _) in held.iter().enumerate().take(m).filter(|(_, h)| !**h) {
        idx[f] = i;
        f += 1;
    }
    let mut out = *x;
    if f == 0 {
        return Some(out);
    }
    let mut l = [[0f32; MAX_UNKNOWNS]; MAX_UNKNOWNS];
    let mut rhs = [0f32; MAX_UNKNOWNS];
    for a in 0..f {
        let i = idx[a];
        rhs[a] = g[i]
            - (0..m)
                .filter(|&j| held[j])
                .map(|j| h[i][j] * x[j])
                .sum::<f32>();
        for b in 0..=a {
            let mut v = h[i][idx[b]];
            for (p, q) in l[a][..b].iter().zip(&l[b][..b]) {
                v -= p * q;
            }
            if a == b {
                if v <= 0.0 || !v.is_finite() {
                    return None;
                }
                l[a][a] = v.sqrt();
            } else {
                l[a][b] = v / l[b][b];
            }
        }
    }
    // L y = rhs, then Lᵀ z = y.
    let mut y = [0f32; MAX_UNKNOWNS];
    for a in 0..f {
        let mut v = rhs[a];
        for k in 0..a {
            v -= l[a][k] * y[k];
        }
        y[a] = v / l[a][a];
    }
    for a in (0..f).rev() {
        let mut v = y[a];
        for k in a + 1..f {
            v -= l[k][a] * y[k];
        }
        y[a] = v / l[a][a];
    }
    for a in 0..f {
        out[idx[a]] = y[a];
    }
    Some(out)
}

/// The regularisation weight for a data Hessian `h` of `m` unknowns: [`LAMBDA`] times its
/// mean diagonal (at least 1e-8, so the problem stays strictly convex).
fn regularisation(h: &[[f32; MAX_UNKNOWNS]; MAX_UNKNOWNS], m: usize) -> f32 {
    let mean = (0..m).map(|i| h[i][i]).sum::<f32>() / m.max(1) as f32;
    (LAMBDA * mean).max(1e-8)
}

fn matrix(k: &[f32; 12]) -> [[f32; 3]; 3] {
    [[k[0], k[1], k[2]], [k[3], k[4], k[5]], [k[6], k[7], k[8]]]
}

fn mul(m: &[[f32; 3]; 3], v: [f32; 3]) -> [f32; 3] {
    std::array::from_fn(|r| m[r][0] * v[0] + m[r][1] * v[1] + m[r][2] * v[2])
}

/// `M a + b` of coefficients `k`.
fn affine(k: &[f32; 12], a: [f32; 3]) -> [f32; 3] {
    let m = mul(&matrix(k), a);
    [m[0] + k[9], m[1] + k[10], m[2] + k[11]]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A projector that turns camera linear light `a` into projector light `M a + b` with a
    /// black level `black` (camera linear): M = gain⁻¹·mix, b = -M · black.
    fn term(gain: f32, mix: f32, black: f32, share: f32) -> Term {
        let a = [[gain, mix, 0.0], [mix, gain, mix], [0.0, mix, gain]];
        let m = inverse(&a).unwrap();
        let b = mul(&m, [black; 3]).map(|v| -v);
        let mut coeffs = [0f32; 12];
        for r in 0..3 {
            coeffs[r * 3..r * 3 + 3].copy_from_slice(&m[r]);
        }
        coeffs[9..].copy_from_slice(&b);
        Term { coeffs, share }
    }

    fn view(terms: &[Term], light: &[[f32; 3]], black: f32) -> [f32; 3] {
        let mut a = [black; 3];
        for (t, l) in terms.iter().zip(light) {
            let inv = inverse(&matrix(&t.coeffs)).unwrap();
            let v = mul(&inv, *l);
            (0..3).for_each(|c| a[c] += v[c]);
        }
        a
    }

    const G: [f32; 3] = [2.2; 3];

    /// Where the split is in range, each projector sends exactly its share and the view is the
    /// target; two projectors stacked reach a target neither reaches alone.
    #[test]
    fn the_split_is_exact_in_range_and_the_other_light_reaches_further() {
        let black = 0.01;
        let terms = [term(0.4, 0.02, black, 0.5), term(0.3, 0.01, black, 0.5)];
        let z = [0.5f32, 0.45, 0.4];
        let a: [f32; 3] = std::array::from_fn(|c| z[c].powf(2.2));
        let light = solve(&terms, 0, z, G);
        let v = view(&terms, &light, black);
        for c in 0..3 {
            assert!((v[c] - a[c]).abs() < 1e-5, "{v:?} against {a:?}");
        }
        // Too bright for either alone (0.4 + 0.02·2 of light at most), within both.
        let z = [0.8f32; 3];
        let a = 0.8f32.powf(2.2);
        for one in [&terms[..1], &terms[1..]] {
            let l = solve(
                &[Term {
                    share: 1.0,
                    ..one[0]
                }],
                0,
                z,
                G,
            );
            let v = view(one, &l, black);
            assert!(v.iter().all(|&v| v < a - 0.05), "alone: {v:?} for {a}");
        }
        // An uneven split: the first projector's share alone would need more than it has.
        let uneven = [
            Term {
                share: 0.9,
                ..terms[0]
            },
            Term {
                share: 0.1,
                ..terms[1]
            },
        ];
        let light = solve(&uneven, 0, z, G);
        let v = view(&uneven, &light, black);
        // Within the regularisation's pull towards the split (`LAMBDA`).
        assert!(v.iter().all(|&v| (v - a).abs() < 1e-2), "{v:?} for {a}");
        assert!(light.iter().flatten().all(|v| (0.0..=1.0).contains(v)));
    }

    fn columns(terms: &[Term]) -> Vec<[f32; 3]> {
        (0..terms.len() * 3)
            .map(|u| {
                let a = inverse(&matrix(&terms[u / 3].coeffs)).unwrap();
                [a[0][u % 3], a[1][u % 3], a[2][u % 3]]
            })
            .collect()
    }

    fn clamped(x: &[f32]) -> Vec<f32> {
        x.iter().map(|v| v.clamp(0.0, 1.0)).collect()
    }

    /// The regularisation weight [`minimise`] uses with `W = I`.
    fn lambda(cols: &[[f32; 3]]) -> f32 {
        let mut h = [[0f32; MAX_UNKNOWNS]; MAX_UNKNOWNS];
        for i in 0..cols.len() {
            h[i][i] = (0..3).map(|c| cols[i][c] * cols[i][c]).sum();
        }
        regularisation(&h, cols.len())
    }

    /// What [`minimise`] minimises, with `W = I`.
    fn objective(cols: &[[f32; 3]], r: [f32; 3], x0: &[f32], x: &[f32]) -> f32 {
        let data: f32 = (0..3)
            .map(|c| ((0..cols.len()).map(|u| cols[u][c] * x[u]).sum::<f32>() - r[c]).powi(2))
            .sum();
        let reg: f32 = x.iter().zip(x0).map(|(a, b)| (a - b).powi(2)).sum();
        data + lambda(cols) * reg
    }

    /// Out of range, the descent finds the bounded minimum: no feasible coordinate step lowers
    /// the objective; and the solve's view is closer to the target (camera-encoded) than the
    /// clamped split's.
    #[test]
    fn out_of_range_the_solution_is_a_bounded_minimum() {
        let black = 0.02;
        let terms = [term(0.35, 0.05, black, 0.7), term(0.25, 0.03, black, 0.3)];
        let cols = columns(&terms);
        for (r, x0) in [
            ([0.6f32, 0.05, 0.3], [1.4f32, 0.1, 0.8, 0.5, -0.1, 0.3]),
            ([0.01, 0.5, 0.55], [0.0, 1.2, 1.3, -0.3, 0.9, 0.7]),
        ] {
            let x = minimise(&cols, r, &x0, [1.0; 3], &clamped(&x0));
            let x = &x[..6];
            let base = objective(&cols, r, &x0, x);
            for u in 0..6 {
                for step in [-1e-3f32, 1e-3] {
                    let mut y = x.to_vec();
                    y[u] = (y[u] + step).clamp(0.0, 1.0);
                    let o = objective(&cols, r, &x0, &y);
                    assert!(
                        o >= base - 1e-7,
                        "r {r:?}: unknown {u} step {step}: {o} < {base}"
                    );
                }
            }
        }
        let enc = |v: [f32; 3]| v.map(|a| a.clamp(0.0, 1.0).powf(1.0 / 2.2));
        for z in [[0.95f32, 0.2, 0.6], [0.05, 0.9, 0.9], [0.1, 0.1, 0.1]] {
            let light = solve(&terms, 1, z, G);
            assert!(light.iter().flatten().all(|v| (0.0..=1.0).contains(v)));
            let a: [f32; 3] = std::array::from_fn(|c| z[c].powf(2.2));
            let clamped: Vec<[f32; 3]> = terms
                .iter()
                .map(|t| {
                    let m = matrix(&t.coeffs);
                    let r: [f32; 3] = std::array::from_fn(|c| t.share * (a[c] - black));
                    mul(&m, r).map(|v| v.clamp(0.0, 1.0))
                })
                .collect();
            let err = |l: &[[f32; 3]]| {
                let v = enc(view(&terms, l, black));
                (0..3).map(|c| (v[c] - z[c]).powi(2)).sum::<f32>()
            };
            assert!(err(&light) <= err(&clamped) + 1e-7, "z {z:?}");
        }
    }

    /// The active set reaches the minimum: a long projected coordinate descent from there
    /// lowers the objective no further.
    #[test]
    fn a_long_descent_finds_nothing_lower() {
        let black = 0.015;
        let terms = [
            term(0.3, 0.04, black, 0.4),
            term(0.45, 0.02, black, 0.35),
            term(0.2, 0.05, black, 0.25),
        ];
        let cols = columns(&terms);
        for (r, x0) in [
            (
                [0.9f32, 0.05, 0.5],
                vec![0.9f32, 1.3, -0.2, 0.5, 1.1, 0.0, 0.2, 0.9, 1.4],
            ),
            (
                [0.3, 0.3, 0.02],
                vec![0.4, 0.5, -0.3, 1.2, 0.2, 0.1, 0.7, 0.9, -0.1],
            ),
        ] {
            let x = minimise(&cols, r, &x0, [1.0; 3], &clamped(&x0));
            let x = x[..9].to_vec();
            let a = objective(&cols, r, &x0, &x);
            let lam = lambda(&cols);
            // Projected coordinate descent, 20 000 sweeps from the answer.
            let mut y = x.clone();
            for _ in 0..20_000 {
                for i in 0..9 {
                    let grad: f32 = (0..3)
                        .map(|c| {
                            cols[i][c] * ((0..9).map(|u| cols[u][c] * y[u]).sum::<f32>() - r[c])
                        })
                        .sum::<f32>()
                        + lam * (y[i] - x0[i]);
                    let hii: f32 = (0..3).map(|c| cols[i][c] * cols[i][c]).sum::<f32>() + lam;
                    y[i] = (y[i] - grad / hii).clamp(0.0, 1.0);
                }
            }
            let b = objective(&cols, r, &x0, &y);
            assert!(
                b >= a - 1e-6 * a.max(1e-3),
                "the descent found {b} below {a}"
            );
        }
    }
}
