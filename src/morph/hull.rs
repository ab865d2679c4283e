//! The convex hull of a mask's pixel centres and the rasterisation of convex polygons (integer
//! pixel coordinates, exact arithmetic).
//!
//! Kept rather than imageproc's `convex_hull` and `draw_polygon`: the fill here sets exactly the
//! pixels whose centres the hull covers, boundary included, which the FOV masks (and so every
//! model's displayable area) are defined by; imageproc's polygon drawing has its own edge rule.

use crate::raster::{Mask, Space};

fn cross(o: (i64, i64), a: (i64, i64), b: (i64, i64)) -> i64 {
    (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0)
}

/// The convex hull of the set pixels' centres, as integer pixel coordinates (x, y) in order
/// around the hull (counter-clockwise with y pointing up, i.e. clockwise as seen on screen),
/// without collinear points. Empty for an empty mask; one point for a single pixel; two points
/// when all set pixels lie on one line.
pub fn convex_hull<S: Space>(mask: &Mask<S>) -> Vec<(i64, i64)> {
    // Only the leftmost and rightmost set pixel of each row can be hull vertices.
    let mut pts = Vec::new();
    for y in 0..mask.height() {
        let row = &mask.data()[y * mask.width()..(y + 1) * mask.width()];
        if let (Some(a), Some(b)) = (row.iter().position(|&v| v), row.iter().rposition(|&v| v)) {
            pts.push((a as i64, y as i64));
            if b != a {
                pts.push((b as i64, y as i64));
            }
        }
    }
    hull_of_points(pts)
}

/// Andrew's monotone chain on integer points (exact arithmetic).
fn hull_of_points(mut pts: Vec<(i64, i64)>) -> Vec<(i64, i64)> {
    pts.sort_unstable();
    pts.dedup();
    if pts.len() <= 2 {
        return pts;
    }
    let mut hull: Vec<(i64, i64)> = Vec::with_capacity(2 * pts.len());
    for &p in &pts {
        while hull.len() >= 2 && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0 {
            hull.pop();
        }
        hull.push(p);
    }
    let lower_len = hull.len() + 1;
    for &p in pts.iter().rev().skip(1) {
        while hull.len() >= lower_len && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0 {
            hull.pop();
        }
        hull.push(p);
    }
    hull.pop(); // the first point again
    hull
}

/// Rasterises a convex polygon given by integer vertices in order (either orientation, as
/// returned by [`convex_hull`]): sets every pixel whose centre lies inside or on the boundary.
/// One vertex sets one pixel; two vertices set the lattice points of the segment. Vertices
/// outside the image are allowed; only pixels inside it are set.
pub fn fill_convex_polygon<S: Space>(poly: &[(i64, i64)], width: usize, height: usize) -> Mask<S> {
    let mut out = Mask::new(width, height);
    if poly.is_empty() || width == 0 || height == 0 {
        return out;
    }
    let xmin = poly.iter().map(|p| p.0).min().unwrap_or(0).max(0);
    let xmax = poly
        .iter()
        .map(|p| p.0)
        .max()
        .unwrap_or(-1)
        .min(width as i64 - 1);
    let ymin = poly.iter().map(|p| p.1).min().unwrap_or(0).max(0);
    let ymax = poly
        .iter()
        .map(|p| p.1)
        .max()
        .unwrap_or(-1)
        .min(height as i64 - 1);
    // Orientation sign so that inside means s·cross(edge, p − a) ≥ 0 for every edge.
    let area2: i64 = (0..poly.len())
        .map(|i| {
            let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
            a.0 * b.1 - b.0 * a.1
        })
        .sum();
    let s = if area2 < 0 { -1 } else { 1 };
    for y in ymin..=ymax {
        // Intersect the row with every edge's half-plane: s·(dx·(y − ay) − dy·(x − ax)) ≥ 0,
        // i.e. d·(x − ax) ≤ c with d = s·dy, c = s·dx·(y − ay).
        let (mut lo, mut hi) = (xmin, xmax);
        if poly.len() >= 2 {
            for i in 0..poly.len() {
                let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
                let (dx, dy) = (b.0 - a.0, b.1 - a.1);
                let (c, d) = (s * dx * (y - a.1), s * dy);
                if d > 0 {
                    hi = hi.min(a.0 + c.div_euclid(d));
                } else if d < 0 {
                    // (x − ax) ≥ c / d = (−c) / (−d), rounded up.
                    lo = lo.max(a.0 - c.div_euclid(-d));
                } else if c < 0 {
                    lo = 1;
                    hi = 0;
                }
            }
        }
        for x in lo..=hi {
            out.set(x as usize, y as usize, true);
        }
    }
    out
}

/// The rasterised convex hull of a mask: every pixel whose centre lies in the hull of the set
/// pixels' centres (so the result contains the mask).
pub fn convex_hull_fill<S: Space>(mask: &Mask<S>) -> Mask<S> {
    fill_convex_polygon(&convex_hull(mask), mask.width(), mask.height())
}
