//! What the `linear` model projects where a desired colour lies outside what the projector can
//! show at that pixel: the reachable colour closest to it as PSNR measures closeness, instead
//! of each channel clamped on its own.
//!
//! The model predicts projector linear light `l = M a + b` from the desired camera linear light
//! `a`, so it implies the forward map `a(l) = M⁻¹ (l − b)`. Where `l` leaves [0, 1]³ (a
//! saturated colour that the surface and the primaries' cross-talk put out of gamut, a dark
//! target below the surface's black), clamping each channel alone ignores that the channels
//! mix: lowering red a little may take more of its cross-talk out of the green than clamping
//! green to zero does. The projected light is instead
//! `argmin over x in [0, 1]³ of ‖W M⁻¹ (x − l)‖²`, a least-squares problem in three bounded
//! unknowns solved exactly ([`box_least_squares_from`]). `W` weights each channel of camera linear
//! light by the slope of the camera's encoding (`v^(1/γc)`), so the error is measured in
//! camera-encoded values as PSNR measures it. The slope is taken first as 1, then as the secant
//! between the target and the view of that first solution: where the target is dark the
//! encoding is steep, and the secant keeps the large out-of-gamut errors from being weighed by
//! the slope at the target alone.
//!
//! On the virtual rig's curved scene (seed 23, the projector's resolution, 48 pairs), this took
//! the closed loop from 0.69 to 0.38 dB below the physical ceiling. Measuring in camera linear
//! light (`W = I`) gained 0.10 dB (192 pairs); weighting by the slope at the target lost 0.10.
//! Reweighting up to five times changed the result by under 0.002 dB. Secants from the clamped
//! light instead of the first solution scored the same and would save one of the two solves,
//! but their weights can differ by 10⁴ (a dark target is steep), and the GPU's f32 then found
//! another point than the CPU's.
//!
//! `shaders/linear.wgsl` computes the same in the same order; this is its CPU reference.

/// A 3×3 matrix, rows first.
type M3 = [[f32; 3]; 3];

/// The projector linear light to project for a desired colour whose unconstrained model output
/// `l` is out of [0, 1]³: per-pixel coefficients `k` (`M` row-major, then `b`), the desired
/// camera value `z` (camera-encoded) and the camera curve's exponents `camera_gamma` (γc, as in
/// `Curves`). Falls back to clamping where `M` cannot be inverted.
pub fn nearest_reachable(
    k: &[f32; 12],
    l: [f32; 3],
    z: [f32; 3],
    camera_gamma: [f32; 3],
) -> [f32; 3] {
    let clamped = l.map(|v| v.clamp(0.0, 1.0));
    let m = [[k[0], k[1], k[2]], [k[3], k[4], k[5]], [k[6], k[7], k[8]]];
    let Some(inv) = inverse(&m) else {
        return clamped;
    };
    let (first, state) = box_least_squares_from(&weighted_gram(&inv, [1.0; 3]), l, clamp_state(l))
        .unwrap_or((clamped, clamp_state(l)));
    // The camera's linear-light change from the target to the view of the first solution.
    let d = [first[0] - l[0], first[1] - l[1], first[2] - l[2]];
    let w: [f32; 3] = std::array::from_fn(|c| {
        // As `Curves::camera_linear`.
        let a0 = z[c].max(0.0).powf(camera_gamma[c]);
        let a1 = a0 + inv[c][0] * d[0] + inv[c][1] * d[1] + inv[c][2] * d[2];
        secant_weight(a0, a1, camera_gamma[c])
    });
    // The weights move the minimum a little: its assignment usually stays.
    box_least_squares_from(&weighted_gram(&inv, w), l, state).map_or(first, |(x, _)| x)
}

/// The weight of one channel of camera linear light in an error measured in camera-encoded
/// values: the encoding's (`v^(1/γc)`, `camera_gamma` = γc) secant between the target `a0` and
/// the view `a1` (camera linear light), the slope at the target where they nearly agree, at
/// least [`WEIGHT_MIN`]. Shared by the joint solve of a set ([`crate::joint::solve`]).
pub fn secant_weight(a0: f32, a1: f32, camera_gamma: f32) -> f32 {
    let inv_g = 1.0 / camera_gamma;
    let enc = |v: f32| v.clamp(0.0, 1.0).powf(inv_g);
    let slope = if (a1 - a0).abs() > SECANT_MIN {
        (enc(a1) - enc(a0)) / (a1 - a0)
    } else {
        inv_g * a0.max(SLOPE_FLOOR).powf(inv_g - 1.0)
    };
    slope.max(WEIGHT_MIN)
}

/// Below this change of camera linear light the secant is taken as the slope at the target.
const SECANT_MIN: f32 = 1e-6;
/// The least weight of a channel. The secant is 0 where the target and the view both lie where
/// the camera clips (both at or below 0, both at or above 1): that channel's error cannot be
/// seen, but a zero weight would leave the minimum not unique, and the GPU pass could pick
/// another minimum than the CPU. The encoding's slope is at least 1/γc ≈ 0.45 inside [0, 1].
const WEIGHT_MIN: f32 = 0.02;
/// Camera linear light at which the slope at the target is taken at least (the encoding's
/// slope is infinite at 0).
const SLOPE_FLOOR: f32 = 1e-4;

/// `M⁻¹` by cofactors; `None` when `M` is singular or nearly (its determinant under 1e-6 of
/// the product of its row norms) or not finite.
pub fn inverse(m: &M3) -> Option<M3> {
    let c00 = m[1][1] * m[2][2] - m[1][2] * m[2][1];
    let c01 = m[1][2] * m[2][0] - m[1][0] * m[2][2];
    let c02 = m[1][0] * m[2][1] - m[1][1] * m[2][0];
    let det = m[0][0] * c00 + m[0][1] * c01 + m[0][2] * c02;
    let norm = |r: &[f32; 3]| (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
    let scale = norm(&m[0]) * norm(&m[1]) * norm(&m[2]);
    if !det.is_finite() || det.abs() <= 1e-6 * scale {
        return None;
    }
    let r = 1.0 / det;
    Some([
        [
            c00 * r,
            (m[0][2] * m[2][1] - m[0][1] * m[2][2]) * r,
            (m[0][1] * m[1][2] - m[0][2] * m[1][1]) * r,
        ],
        [
            c01 * r,
            (m[0][0] * m[2][2] - m[0][2] * m[2][0]) * r,
            (m[0][2] * m[1][0] - m[0][0] * m[1][2]) * r,
        ],
        [
            c02 * r,
            (m[0][1] * m[2][0] - m[0][0] * m[2][1]) * r,
            (m[0][0] * m[1][1] - m[0][1] * m[1][0]) * r,
        ],
    ])
}

/// `(W A)ᵀ (W A)` for `W = diag(w)`.
fn weighted_gram(a: &M3, w: [f32; 3]) -> M3 {
    std::array::from_fn(|i| {
        std::array::from_fn(|j| (0..3).map(|r| w[r] * w[r] * a[r][i] * a[r][j]).sum())
    })
}

/// An assignment per coordinate: 0 free, 1 held at 0, 2 held at 1.
type State = [u32; 3];

/// The assignment clamping `u` suggests: each coordinate outside [0, 1] held at the bound it
/// crossed, the others free.
fn clamp_state(u: [f32; 3]) -> State {
    u.map(|v| {
        if v < 0.0 {
            1
        } else if v > 1.0 {
            2
        } else {
            0
        }
    })
}

/// Steps of the active-set search before every assignment is tried.
const ACTIVE_SET_STEPS: usize = 4;

/// `argmin over x in [0, 1]³ of (x − u)ᵀ Q (x − u)` for a symmetric positive (semi)definite `Q`,
/// searched from the assignment `start`, and the assignment of the minimum (to start a related
/// problem from). `None` if no assignment gives a feasible point (only with a degenerate `Q`).
///
/// A primal-dual active-set search: at each step the free coordinates solve the stationarity
/// equations with the held ones at their bounds ([`solve`]); a free coordinate that left
/// [0, 1] is held at the bound it crossed, and a held one whose gradient pulls it into the box
/// is freed. When a step changes nothing, the point is feasible and satisfies the optimality
/// conditions ([`optimal`]), so it is the minimum (the problem is convex). From the clamping
/// assignment that is usually the first or second step. The search can cycle on badly
/// conditioned `Q`, so after [`ACTIVE_SET_STEPS`] steps every assignment is tried and the
/// feasible point of least cost kept (the minimum is one of them). On the GPU, where the pixels
/// of one wave wait for the slowest, a wave then mostly waits for a few steps instead of all 27
/// assignments.
pub fn box_least_squares_from(q: &M3, u: [f32; 3], start: State) -> Option<([f32; 3], State)> {
    active_set(q, u, start).or_else(|| every_assignment(q, u))
}

/// The active-set search of [`box_least_squares_from`]; `None` where it did not settle within
/// [`ACTIVE_SET_STEPS`] steps or settled on a point that is not the minimum (NaN, a singular
/// system).
fn active_set(q: &M3, u: [f32; 3], start: State) -> Option<([f32; 3], State)> {
    let mut state = start;
    for _ in 0..ACTIVE_SET_STEPS {
        let x = solve(q, u, state)?;
        let next = next_state(q, u, x, state);
        if next == state {
            return (feasible(x) && optimal(q, u, x, state)).then_some((x, state));
        }
        state = next;
    }
    None
}

/// Every assignment tried, the feasible point of least cost kept.
fn every_assignment(q: &M3, u: [f32; 3]) -> Option<([f32; 3], State)> {
    let mut best: Option<(f32, [f32; 3], State)> = None;
    for s in 0..27u32 {
        let state = [s % 3, (s / 3) % 3, s / 9];
        let Some(x) = solve(q, u, state).filter(|&x| feasible(x)) else {
            continue;
        };
        let d = [x[0] - u[0], x[1] - u[1], x[2] - u[2]];
        let cost: f32 = (0..3)
            .map(|i| d[i] * (0..3).map(|j| q[i][j] * d[j]).sum::<f32>())
            .sum();
        if best.is_none_or(|(b, _, _)| cost < b) {
            best = Some((cost, x, state));
        }
    }
    best.map(|(_, x, state)| (x, state))
}

/// The active-set step: from the point `x` of assignment `state`, hold each free coordinate
/// outside [0, 1] at the bound it crossed and free each held one whose gradient `Q (x − u)`
/// points into the box. NaN changes nothing (every comparison is false).
fn next_state(q: &M3, u: [f32; 3], x: [f32; 3], state: State) -> State {
    std::array::from_fn(|c| {
        let g: f32 = (0..3).map(|j| q[c][j] * (x[j] - u[j])).sum();
        match state[c] {
            1 if g < 0.0 => 0,
            2 if g > 0.0 => 0,
            0 if x[c] < 0.0 => 1,
            0 if x[c] > 1.0 => 2,
            s => s,
        }
    })
}

/// Inside [0, 1]³ (NaN is not).
fn feasible(x: [f32; 3]) -> bool {
    x.iter().all(|v| (0.0..=1.0).contains(v))
}

/// The point of one assignment (`state`, per coordinate: 0 free, 1 held at 0, 2 held at 1): the
/// held coordinates at their bounds, the free ones solving the stationarity equations
/// `Q_ff (x_f − u_f) = −Q_fc (x_c − u_c)`, whether or not that lands in [0, 1]. `None` when the
/// equations are singular.
fn solve(q: &M3, u: [f32; 3], state: State) -> Option<[f32; 3]> {
    let mut x: [f32; 3] = std::array::from_fn(|c| match state[c] {
        1 => 0.0,
        2 => 1.0,
        _ => u[c],
    });
    // The right-hand side −Q_fc (x_c − u_c) for every row.
    let r: [f32; 3] = std::array::from_fn(|i| {
        -(0..3)
            .filter(|&c| state[c] != 0)
            .map(|c| q[i][c] * (x[c] - u[c]))
            .sum::<f32>()
    });
    let (mut free, mut nfree) = ([0usize; 3], 0);
    for c in (0..3).filter(|&c| state[c] == 0) {
        free[nfree] = c;
        nfree += 1;
    }
    match (nfree, free) {
        (1, [i, ..]) => {
            if q[i][i] <= 0.0 {
                return None;
            }
            x[i] = u[i] + r[i] / q[i][i];
        }
        (2, [i, j, _]) => {
            let det = q[i][i] * q[j][j] - q[i][j] * q[j][i];
            if det <= 0.0 {
                return None;
            }
            x[i] = u[i] + (r[i] * q[j][j] - q[i][j] * r[j]) / det;
            x[j] = u[j] + (q[i][i] * r[j] - q[j][i] * r[i]) / det;
        }
        // All held (a corner), or all free (u itself).
        _ => {}
    }
    Some(x)
}

/// The optimality (KKT) conditions at a feasible point of assignment `state`: the gradient
/// `Q (x − u)` pushes every held coordinate against its bound (free ones are stationary by
/// construction). Sufficient for the minimum, the problem being convex.
fn optimal(q: &M3, u: [f32; 3], x: [f32; 3], state: [u32; 3]) -> bool {
    (0..3).all(|c| {
        let g: f32 = (0..3).map(|j| q[c][j] * (x[j] - u[j])).sum();
        match state[c] {
            1 => g >= 0.0,
            2 => g <= 0.0,
            _ => true,
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cost(q: &M3, u: [f32; 3], x: [f32; 3]) -> f32 {
        let d = [x[0] - u[0], x[1] - u[1], x[2] - u[2]];
        (0..3)
            .map(|i| d[i] * (0..3).map(|j| q[i][j] * d[j]).sum::<f32>())
            .sum()
    }

    #[test]
    fn the_box_solution_is_no_worse_than_any_point_of_a_fine_grid() {
        // Correlated channels and a target far outside the box in two of them.
        let a = [[1.2, -0.4, 0.1], [-0.3, 0.9, 0.35], [0.05, 0.2, 1.4]];
        let q = weighted_gram(&a, [1.0, 2.5, 0.7]);
        for u in [
            [1.3, -0.2, 0.5],
            [-0.4, -0.1, 1.6],
            [0.4, 0.5, 0.6],
            [2.0, 2.0, -1.0],
        ] {
            let (x, _) = box_least_squares_from(&q, u, clamp_state(u)).expect("a feasible point");
            assert!(x.iter().all(|v| (0.0..=1.0).contains(v)), "{x:?}");
            let best = cost(&q, u, x);
            let n = 40;
            for i in 0..=n {
                for j in 0..=n {
                    for k in 0..=n {
                        let g = [
                            i as f32 / n as f32,
                            j as f32 / n as f32,
                            k as f32 / n as f32,
                        ];
                        assert!(
                            best <= cost(&q, u, g) + 1e-5,
                            "u {u:?}: {x:?} costs {best}, {g:?} costs {}",
                            cost(&q, u, g)
                        );
                    }
                }
            }
        }
        // Inside the box the target itself.
        assert_eq!(
            box_least_squares_from(&q, [0.4, 0.5, 0.6], [0; 3]).map(|(x, _)| x),
            Some([0.4, 0.5, 0.6])
        );
    }

    /// The active-set search settles on the minimum that trying every assignment finds, within
    /// its steps on nearly every problem: random cross-talk up to ±0.6, weights 0.02–3 and
    /// targets up to a unit outside the box.
    #[test]
    fn the_active_set_search_finds_the_minimum_in_a_few_steps() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::ChaCha8Rng::seed_from_u64(5);
        let (mut settled, mut total) = (0, 0);
        for _ in 0..20_000 {
            let a: M3 = std::array::from_fn(|i| {
                std::array::from_fn(|j| {
                    if i == j {
                        rng.random_range(0.5..1.5)
                    } else {
                        rng.random_range(-0.6..0.6)
                    }
                })
            });
            let w: [f32; 3] = std::array::from_fn(|_| rng.random_range(0.02..3.0));
            let u: [f32; 3] = std::array::from_fn(|_| rng.random_range(-1.0..2.0));
            let q = weighted_gram(&a, w);
            let Some((all, _)) = every_assignment(&q, u) else {
                continue;
            };
            total += 1;
            let Some((x, state)) = active_set(&q, u, clamp_state(u)) else {
                continue;
            };
            settled += 1;
            assert!(feasible(x) && optimal(&q, u, x, state), "{x:?} {state:?}");
            let (cx, ca) = (cost(&q, u, x), cost(&q, u, all));
            assert!(
                cx <= ca + 1e-5 * (1.0 + ca),
                "u {u:?}: {x:?} costs {cx}, {all:?} {ca}"
            );
            // Started from its own minimum's assignment, the search stops at once.
            assert_eq!(active_set(&q, u, state).map(|(_, s)| s), Some(state));
        }
        assert!(total > 19_000, "{total}");
        assert!(
            settled as f64 > 0.99 * total as f64,
            "settled on {settled} of {total}"
        );
    }

    #[test]
    fn the_inverse_inverts_and_refuses_a_singular_matrix() {
        let m = [[1.3, 0.2, -0.1], [0.05, 0.9, 0.3], [-0.2, 0.1, 1.1]];
        let inv = inverse(&m).expect("invertible");
        for (i, row) in m.iter().enumerate() {
            for j in 0..3 {
                let p: f32 = row.iter().zip(&inv).map(|(a, r)| a * r[j]).sum();
                assert!(
                    (p - if i == j { 1.0 } else { 0.0 }).abs() < 1e-5,
                    "{i},{j}: {p}"
                );
            }
        }
        assert_eq!(
            inverse(&[[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 1.0, 1.0]]),
            None
        );
        assert_eq!(
            inverse(&[[f32::NAN, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
            None
        );
    }

    #[test]
    fn an_out_of_gamut_target_trades_channels_instead_of_clamping_each() {
        // Strong cross-talk: the camera's green sees 40 % of the projector's red.
        let forward = [[1.0, 0.0, 0.0], [0.4, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let m = inverse(&forward).expect("invertible");
        let k = [
            m[0][0], m[0][1], m[0][2], m[1][0], m[1][1], m[1][2], m[2][0], m[2][1], m[2][2], 0.0,
            0.0, 0.0,
        ];
        let gamma = [2.2f32; 3];
        // Bright red with a dark green: the model asks for negative green.
        let z = [0.9f32, 0.2, 0.5];
        let a: [f32; 3] = std::array::from_fn(|c| z[c].powf(gamma[c]));
        let l: [f32; 3] = std::array::from_fn(|c| (0..3).map(|j| k[c * 3 + j] * a[j]).sum());
        assert!(l[1] < 0.0, "{l:?}");
        let x = nearest_reachable(&k, l, z, gamma);
        let seen = |x: [f32; 3]| -> f32 {
            // Squared error in camera-encoded values of the view of x.
            (0..3)
                .map(|c| {
                    let v: f32 = (0..3).map(|j| forward[c][j] * x[j]).sum();
                    (v.clamp(0.0, 1.0).powf(1.0 / 2.2) - z[c]).powi(2)
                })
                .sum()
        };
        let clamped = l.map(|v| v.clamp(0.0, 1.0));
        assert!(
            x[0] < clamped[0],
            "red is lowered: {x:?} against {clamped:?}"
        );
        assert!(
            seen(x) < 0.8 * seen(clamped),
            "closer as PSNR sees it: {} against {}",
            seen(x),
            seen(clamped)
        );
    }
}
