//! Geometry from structured light, for the two-step baselines (`linear-sl`, `compennet-sl`):
//! turns the decoded camera→projector correspondence into the network→camera sampling grid.
//!
//! The network image is placed on the canvas (a rectangle of projector pixels, stretched to fill
//! it), so network pixel `p = (i, j)` sits at projector position
//! `P(p) = canvas.origin + (i, j) · (canvas.size − 1) / (network.size − 1)`. For every valid camera
//! pixel `q` with decoded projector position `P(q)`, its network position `n(q)` follows by
//! inverting that placement. The camera position seen at network pixel `p` is then estimated by a
//! weighted local affine fit `q ≈ c + A (n(q) − p)` over the camera pixels whose `n(q)` fall
//! within a small window around `p` (tent weights); `c` is the estimate. Unlike a plain average,
//! the fit is not biased where the camera samples the projector unevenly. Network pixels with too
//! little support (outside the camera's view, occlusions, decoding holes) are filled by repeated
//! averaging of filled neighbours (membrane interpolation), which extends the geometry smoothly.

use crate::error::{Error, Result};
use crate::patterns::Correspondence;
use crate::raster::{Camera, ImageSize, Mask, Network, Rect};
use crate::sample::{Grid, pixel_to_norm};

/// The grid and how much of it came from measurements.
#[derive(Clone, Debug)]
pub struct SlGrid {
    pub grid: Grid<Network, Camera>,
    /// Network pixels estimated from structured light (the rest were filled).
    pub measured: Mask<Network>,
}

/// Window half-width of the local fit, in network pixels.
const RADIUS: f64 = 1.5;

/// Builds the network→camera grid from a correspondence; `canvas` is where network images were
/// placed in projector pixels (the full projector frame unless the capture placed them elsewhere).
pub fn grid_from_correspondence(
    corr: &Correspondence,
    canvas: Rect,
    network: ImageSize,
) -> Result<SlGrid> {
    let ImageSize {
        width: nw,
        height: nh,
    } = network;
    let ImageSize {
        width: pw,
        height: ph,
    } = corr.projector;
    if canvas.width < 2
        || canvas.height < 2
        || canvas.x + canvas.width > pw
        || canvas.y + canvas.height > ph
    {
        return Err(Error::Input(format!(
            "canvas {canvas} does not fit in the {pw}x{ph} projector frame"
        )));
    }
    if nw < 2 || nh < 2 {
        return Err(Error::Input(format!("network size {nw}x{nh} is too small")));
    }
    // Projector pixels per network pixel along each axis.
    let sx = (canvas.width - 1) as f64 / (nw - 1) as f64;
    let sy = (canvas.height - 1) as f64 / (nh - 1) as f64;
    let ImageSize {
        width: cw,
        height: ch,
    } = corr.size();
    let (m, r) = local_moments(corr, canvas, network, (sx, sy));
    let pos = local_fits(&m, &r);
    let measured = Mask::from_fn(nw, nh, |i, j| pos[j * nw + i].is_some());
    if measured.count() == 0 {
        return Err(Error::Failed(
            "structured light: no network pixel is seen by the camera (empty correspondence)"
                .into(),
        ));
    }
    let filled = fill_holes(&pos, nw, nh);
    let grid = Grid::from_fn(nw, nh, |i, j| {
        let [x, y] = filled[j * nw + i];
        [pixel_to_norm(x as f32, cw), pixel_to_norm(y as f32, ch)]
    });
    Ok(SlGrid { grid, measured })
}

/// The weighted moments of the local fit at every network pixel (row-major): per pixel, of
/// `[1, dn_x, dn_y]` (`Σw, Σw dx, Σw dy, Σw dx², Σw dx dy, Σw dy²`) and of the camera position
/// `q` (`Σw q, Σw q dx, Σw q dy` for `q = (cx, cy)`, camera pixels). `dn` is a camera pixel's
/// network position minus the network pixel's, in network pixels; `(sx, sy)` are projector
/// pixels per network pixel.
fn local_moments(
    corr: &Correspondence,
    canvas: Rect,
    ImageSize {
        width: nw,
        height: nh,
    }: ImageSize,
    (sx, sy): (f64, f64),
) -> (Vec<[f64; 6]>, Vec<[f64; 6]>) {
    let mut m = vec![[0f64; 6]; nw * nh]; // Σw, Σw dx, Σw dy, Σw dx², Σw dx dy, Σw dy²
    let mut r = vec![[0f64; 6]; nw * nh]; // Σw q, Σw q dx, Σw q dy, for q = (cx, cy)
    let ImageSize {
        width: cw,
        height: ch,
    } = corr.size();
    let reach = RADIUS.ceil() as i64;
    for cy in 0..ch {
        for cx in 0..cw {
            let Some([px, py]) = corr.get(cx, cy) else {
                continue;
            };
            let nx = (px as f64 - canvas.x as f64) / sx;
            let ny = (py as f64 - canvas.y as f64) / sy;
            let (bx, by) = (nx.round() as i64, ny.round() as i64);
            for j in by - reach..=by + reach {
                for i in bx - reach..=bx + reach {
                    if i < 0 || j < 0 || i >= nw as i64 || j >= nh as i64 {
                        continue;
                    }
                    let (dx, dy) = (nx - i as f64, ny - j as f64);
                    let w = (1.0 - dx.abs() / RADIUS).max(0.0) * (1.0 - dy.abs() / RADIUS).max(0.0);
                    if w <= 0.0 {
                        continue;
                    }
                    let k = j as usize * nw + i as usize;
                    let mm = &mut m[k];
                    mm[0] += w;
                    mm[1] += w * dx;
                    mm[2] += w * dy;
                    mm[3] += w * dx * dx;
                    mm[4] += w * dx * dy;
                    mm[5] += w * dy * dy;
                    let rr = &mut r[k];
                    for (a, q) in [cx as f64, cy as f64].into_iter().enumerate() {
                        rr[a * 3] += w * q;
                        rr[a * 3 + 1] += w * q * dx;
                        rr[a * 3 + 2] += w * q * dy;
                    }
                }
            }
        }
    }
    (m, r)
}

/// The camera position (camera pixels) at each network pixel from its moments: the constant
/// term of the weighted affine fit, or the weighted mean where the samples are not spread
/// enough; `None` with less than about one camera sample's weight.
fn local_fits(m: &[[f64; 6]], r: &[[f64; 6]]) -> Vec<Option<[f64; 2]>> {
    let n = m.len();
    let mut pos: Vec<Option<[f64; 2]>> = vec![None; n];
    for k in 0..n {
        let mm = &m[k];
        if mm[0] < 1.0 {
            continue; // less than about one camera sample's weight
        }
        let a = nalgebra::Matrix3::new(
            mm[0], mm[1], mm[2], mm[1], mm[3], mm[4], mm[2], mm[4], mm[5],
        );
        let est = |o: usize| -> Option<f64> {
            let b = nalgebra::Vector3::new(r[k][o * 3], r[k][o * 3 + 1], r[k][o * 3 + 2]);
            // Well-spread samples: solve the affine fit; otherwise fall back to the weighted mean.
            match a.cholesky() {
                Some(c) if a.determinant() > 1e-6 * mm[0].powi(3) => Some(c.solve(&b)[0]),
                _ => Some(b[0] / mm[0]),
            }
        };
        if let (Some(x), Some(y)) = (est(0), est(1)) {
            pos[k] = Some([x, y]);
        }
    }
    pos
}

/// Membrane fill: unknown cells take the mean of known or already filled 4-neighbours, repeated
/// until every cell is set; then a few Jacobi sweeps smooth the filled cells only.
fn fill_holes(pos: &[Option<[f64; 2]>], w: usize, h: usize) -> Vec<[f64; 2]> {
    let mut cur: Vec<Option<[f64; 2]>> = pos.to_vec();
    loop {
        let next: Vec<Option<[f64; 2]>> = (0..w * h)
            .map(|k| cur[k].or_else(|| neighbour_mean(k % w, k / w, w, h, |i| cur[i])))
            .collect();
        let done = next.iter().all(Option::is_some);
        cur = next;
        if done {
            break;
        }
    }
    let mut out: Vec<[f64; 2]> = cur.into_iter().map(|v| v.unwrap_or([0.0, 0.0])).collect();
    for _ in 0..50 {
        let prev = out.clone();
        for k in (0..w * h).filter(|&k| pos[k].is_none()) {
            if let Some(v) = neighbour_mean(k % w, k / w, w, h, |i| Some(prev[i])) {
                out[k] = v;
            }
        }
    }
    out
}

/// Mean of the defined values among the 4-neighbours of cell (x, y), if any.
fn neighbour_mean(
    x: usize,
    y: usize,
    w: usize,
    h: usize,
    value: impl Fn(usize) -> Option<[f64; 2]>,
) -> Option<[f64; 2]> {
    let (mut s, mut n) = ([0f64; 2], 0);
    for (dx, dy) in [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)] {
        let (nx, ny) = (x as i64 + dx, y as i64 + dy);
        if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
            continue;
        }
        if let Some(v) = value(ny as usize * w + nx as usize) {
            s[0] += v[0];
            s[1] += v[1];
            n += 1;
        }
    }
    (n > 0).then(|| [s[0] / n as f64, s[1] / n as f64])
}
