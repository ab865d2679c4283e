//! The colour solve of the `linear` rung: per-pixel normal equations of the inverse model
//! (camera linear light → projector linear light), solved in closed form with a ridge pull towards
//! one global model.
//!
//! Inputs are the captures (camera pixels), the projector images (network pixels) and the grid
//! that maps the model's lattice (network pixels, or a finer lattice) to camera positions; each
//! lattice pixel's pairs are sampled in place ([`Frames`], [`Stack`]). Residuals are in linear projector
//! light.

use rayon::prelude::*;

use super::curve::{CURVE_SAMPLES, CURVE_SWEEPS, fit_curves};
use super::model::{Coefficients, Curves};
use super::normal::{Normal, PowTable, global_solution};
use super::settings::ColourSolve;
use super::stack::{Captures, Frames, Resize, Stack};
use crate::raster::{Camera, ImageSize, NetImage, Network, ReadRgb};
use crate::sample::Grid;

/// Curves (searched on the first `curve_pairs` pairs) and per-pixel coefficients at full
/// resolution on all pairs, for a fixed grid: the model's lattice is the grid's size. The projector images (network size, or already the
/// lattice's) are resampled bilinearly onto the lattice where it differs: the projector shows an
/// image stretched bilinearly over the canvas (half-pixel centres), so that gives, at each
/// lattice pixel, close to the value the projector showed there. Captures are sampled at the
/// grid's positions and images resampled pixel by pixel ([`Frames`], [`Stack`]), never whole.
pub(super) fn fit_colour<C: ReadRgb<Camera>>(
    captures: &[C],
    targets: &[NetImage],
    grid: &Grid<Network, Camera>,
    start: Curves,
    ridge: f32,
    (curve_pairs, solve): (usize, ColourSolve),
) -> (Curves, Coefficients, f64) {
    let stride = grid
        .size()
        .width
        .max(grid.size().height)
        .div_ceil(CURVE_SAMPLES)
        .max(1);
    let t = std::time::Instant::now();
    // The curves are a handful of global exponents: the first pairs fix them (24 pairs at 32
    // samples a side are 18 432 samples a channel), and a fit on more pairs that starts with
    // these keeps them, which lets pairs added later grow its sums ([`ColourSums`]).
    let k = curve_pairs.clamp(1, captures.len());
    let curves = fit_curves(
        &Frames::new(&captures[..k]),
        &Stack::<f32>::new(&targets[..k]),
        grid,
        start,
        ridge,
        stride,
        CURVE_SWEEPS,
    );
    let curves_s = t.elapsed().as_secs_f64();
    let (caps, shown) = (Frames::new(captures), Stack::<f32>::new(targets));
    let (coeffs, loss) = solve_colour(&caps, &shown, grid, &curves, (ridge, solve));
    tracing::debug!(
        "colour on {} pairs at {}: curves {curves_s:.1} s (on the first {k}), coefficients \
         {:.1} s",
        captures.len(),
        grid.size(),
        t.elapsed().as_secs_f64() - curves_s
    );
    (curves, coeffs, loss)
}

/// The lattice pixels the ridge prior is estimated on: every `PRIOR_STRIDE`-th along each
/// axis. The prior is one colour model for the whole lattice (4×3 numbers), fitted on the pooled
/// samples; a sixteenth of them is still hundreds of thousands of samples, and pooling all of
/// them meant holding every pixel's normal equations at once (248 bytes a pixel: 119 MB at
/// 800×600, 514 MB at 1920×1080) before any pixel could be solved.
const PRIOR_STRIDE: usize = 4;

/// Solves the per-pixel coefficients on the grid's lattice; returns them and the mean squared
/// residual (linear light). Each pixel's normal equations are made where they are needed
/// ([`solve_normals`]), never held all at once.
fn solve_colour<C: Captures>(
    caps: &C,
    shown: &Stack,
    grid: &Grid<Network, Camera>,
    curves: &Curves,
    (ridge, solve): (f32, ColourSolve),
) -> (Coefficients, f64) {
    let n = caps.images();
    let resize = shown.resize_to(grid.size());
    let tables = (
        PowTable::new(curves.camera_gamma),
        PowTable::new(curves.projector_gamma),
    );
    let normal_at = |p: usize| -> Normal {
        let mut ne = Normal::default();
        add_pairs(&mut ne, (caps, shown, &resize), grid, &tables, p);
        ne
    };
    solve_normals(grid.size(), n, normal_at, (ridge, solve))
}

/// Adds every pair of `caps` and `shown` at lattice pixel `p` to `ne`, in pair order: features
/// of the capture sampled at the grid's position (camera linear light through the camera
/// curve), targets of the projector image resampled onto the lattice (projector linear light).
#[inline]
fn add_pairs<C: Captures>(
    ne: &mut Normal,
    (caps, shown, resize): (&C, &Stack, &Resize),
    grid: &Grid<Network, Camera>,
    (camera, projector): &(PowTable, PowTable),
    p: usize,
) {
    let [gx, gy] = grid.data()[p];
    let taps = caps.taps(gx, gy);
    for i in 0..caps.images() {
        let a = camera.features(&caps.sample(&taps, i));
        let y = projector.linear(&shown.resampled(resize, p, i));
        ne.add(&a, &y);
    }
}

/// Solves the coefficients of a `size` lattice from each pixel's normal equations over `n`
/// pairs (`normal_at`), with the ridge pull towards one global model; returns them and the
/// mean squared residual (linear light). Two passes: the prior on a subsample
/// ([`PRIOR_STRIDE`]), then each pixel solved and scored; [`ColourSolve::Global`] stops after
/// the first, with the prior at every pixel and its residual on the subsample.
fn solve_normals(
    size: ImageSize,
    n: usize,
    normal_at: impl Fn(usize) -> Normal + Sync,
    (ridge, solve): (f32, ColourSolve),
) -> (Coefficients, f64) {
    let ImageSize {
        width: w,
        height: h,
    } = size;
    // The prior: per sampled row in parallel, then the rows merged in order, so that a run
    // gives the same prior as the last.
    let rows: Vec<Normal> = (0..h)
        .into_par_iter()
        .step_by(PRIOR_STRIDE)
        .map(|y| {
            let mut row = Normal::default();
            for x in (0..w).step_by(PRIOR_STRIDE) {
                row.merge(&normal_at(y * w + x));
            }
            row
        })
        .collect();
    let mut global = Normal::default();
    for row in &rows {
        global.merge(row);
    }
    let sampled = h.div_ceil(PRIOR_STRIDE) * w.div_ceil(PRIOR_STRIDE);
    let global_beta = global_solution(&global, n * sampled);
    if solve == ColourSolve::Global {
        let loss = global.sse(&global_beta) / (n.max(1) * sampled.max(1) * 3) as f64;
        let data = vec![global_beta; w * h];
        return (
            Coefficients {
                width: w,
                height: h,
                data,
            },
            loss,
        );
    }
    let lambda = ridge as f64;
    let (data, sse): (Vec<[f32; 12]>, Vec<f64>) = (0..w * h)
        .into_par_iter()
        .map(|p| {
            let ne = normal_at(p);
            let k = ne.solve(lambda, &global_beta);
            (k, ne.sse(&k))
        })
        .unzip();
    // The squared residual from each pixel's sums (one pass over the data, not two), summed in
    // pixel order, so that a run reports the same loss as the last.
    let sse: f64 = sse.iter().sum();
    (
        Coefficients {
            width: w,
            height: h,
            data,
        },
        sse / (n.max(1) * w * h * 3) as f64,
    )
}

/// The colour solve's sums kept between pairs: every lattice pixel's normal equations on a
/// fixed grid (network pixels → camera coordinates) and fixed response curves, to which pairs
/// are added as they arrive and which are solved at any time ([`ColourSums::solve`]). A
/// calibration adds its sampling pairs and then each closed-loop pair while the next is
/// captured, so the fit on every pair costs one solve after the last capture. Pairs added in
/// order give the coefficients [`fit_colour`] gives on the same pairs with these curves, to
/// the bit (the same sums, in the same order). Memory: 248 bytes a lattice pixel (119 MB at
/// 800×600).
pub struct ColourSums {
    grid: Grid<Network, Camera>,
    curves: Curves,
    ridge: f32,
    tables: (PowTable, PowTable),
    normals: Vec<Normal>,
    pairs: usize,
    /// The projector images' size, fixed by the first pairs added (network pixels).
    shown_size: Option<ImageSize>,
}

impl ColourSums {
    /// No pairs yet, on `grid` (its size is the lattice) with `curves` and the ridge weight of
    /// the fit ([`super::FitSettings::ridge`]).
    pub fn new(grid: Grid<Network, Camera>, curves: Curves, ridge: f32) -> Self {
        let pixels = grid.size().width * grid.size().height;
        Self {
            tables: (
                PowTable::new(curves.camera_gamma),
                PowTable::new(curves.projector_gamma),
            ),
            grid,
            curves,
            ridge,
            normals: vec![Normal::default(); pixels],
            pairs: 0,
            shown_size: None,
        }
    }

    /// Pairs added so far.
    pub fn pairs(&self) -> usize {
        self.pairs
    }

    /// The curves the sums are made with.
    pub fn curves(&self) -> Curves {
        self.curves
    }

    /// Adds pairs: captures (camera space, masked as the fit masks them) and the projector
    /// images shown (network space), in order. Every capture must be of one size and every
    /// projector image of the size of those added before.
    pub fn add<C: ReadRgb<Camera>>(
        &mut self,
        captures: &[C],
        targets: &[NetImage],
    ) -> crate::error::Result<()> {
        use crate::error::Error;
        if captures.len() != targets.len() {
            return Err(Error::Input(format!(
                "colour sums need as many captures as projector images, got {} and {}",
                captures.len(),
                targets.len()
            )));
        }
        let Some(first) = targets.first() else {
            return Ok(());
        };
        let size = *self.shown_size.get_or_insert(first.size());
        if let Some(t) = targets.iter().find(|t| t.size() != size) {
            return Err(Error::Shape(format!(
                "colour sums of {size} projector images cannot take one of {}",
                t.size()
            )));
        }
        let cam = captures[0].dimensions();
        if let Some(c) = captures.iter().find(|c| c.dimensions() != cam) {
            return Err(Error::Shape(format!(
                "captures differ in size: {cam} and {}",
                c.dimensions()
            )));
        }
        let (caps, shown) = (Frames::new(captures), Stack::<f32>::new(targets));
        let resize = shown.resize_to(self.grid.size());
        let (grid, tables) = (&self.grid, &self.tables);
        self.normals
            .par_iter_mut()
            .enumerate()
            .for_each(|(p, ne)| add_pairs(ne, (&caps, &shown, &resize), grid, tables, p));
        self.pairs += captures.len();
        Ok(())
    }

    /// The coefficients on the pairs added so far and their mean squared residual (linear
    /// light), as [`fit_colour`] solves them.
    pub fn solve(&self) -> (Coefficients, f64) {
        solve_normals(
            self.grid.size(),
            self.pairs,
            |p| self.normals[p],
            (self.ridge, ColourSolve::PerPixel),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::super::stack::tests::random_images;
    use super::*;
    use crate::raster::CamImage;
    use rand::{RngExt, SeedableRng};

    /// Pairs added to the sums a few at a time solve to the coefficients and loss of the solve
    /// on all of them at once, to the bit, on a lattice finer than the projector images (so
    /// they are resampled) and a grid that reaches outside the captures; a pair more changes
    /// them; and pairs of another size are refused, naming both sizes.
    #[test]
    fn sums_grown_in_steps_solve_as_the_whole_solve_does() {
        let caps: Vec<CamImage> = random_images(7, 12, 9, 3);
        let shown: Vec<NetImage> = random_images(7, 6, 5, 4);
        let mut rng = rand::rngs::ChaCha8Rng::seed_from_u64(5);
        let grid = Grid::<Network, Camera>::from_fn(10, 8, |_, _| {
            [rng.random_range(-1.2..1.2), rng.random_range(-1.2..1.2)]
        });
        let curves = Curves {
            camera_gamma: [2.1, 2.1, 2.1],
            projector_gamma: [2.0, 2.3, 1.9],
        };
        let ridge = 0.012;
        let (whole, whole_loss) = solve_colour(
            &Frames::new(&caps),
            &Stack::<f32>::new(&shown),
            &grid,
            &curves,
            (ridge, ColourSolve::PerPixel),
        );
        let mut sums = ColourSums::new(grid.clone(), curves, ridge);
        let mut partial = None;
        for range in [0..3, 3..4, 4..7] {
            sums.add(&caps[range.clone()], &shown[range])
                .expect("pairs of one size");
            if sums.pairs() == 4 {
                partial = Some(sums.solve());
            }
        }
        assert_eq!(sums.pairs(), 7);
        let (grown, grown_loss) = sums.solve();
        assert_eq!(grown, whole);
        assert!(whole_loss.is_finite() && whole_loss > 0.0);
        assert_eq!(grown_loss.to_bits(), whole_loss.to_bits());
        let (partial, _) = partial.expect("solved after four pairs");
        assert_ne!(partial, whole, "three pairs more change the coefficients");

        let odd: Vec<NetImage> = random_images(1, 7, 5, 6);
        let err = sums.add(&caps[..1], &odd).expect_err("another size");
        assert!(
            err.to_string().contains("6x5") && err.to_string().contains("7x5"),
            "{err}"
        );
        assert_eq!(sums.pairs(), 7, "nothing added from a refused add");
    }
}
