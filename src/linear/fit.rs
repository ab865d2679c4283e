//! Training entry points of the `linear` rung: the full fit ([`fit`]: geometry, then colour),
//! the geometry alone ([`fit_geometry`], for the CompenNet++ variants) and the colour alone on a
//! fixed grid ([`fit_on_grid`], for `linear-sl`), with their settings and report.
//!
//! Inputs: captures in camera space (camera pixels, encoded values in \[0,1\]) and the projector
//! images shown, in network space (network pixels).

use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::colour::fit_colour;
use super::geometry::{fit_warp, refine_geometry};
use super::model::{Curves, Geometry, LinearModel, learned_grid};
use super::settings::FitSettings;
use crate::error::{Error, Result};
use crate::raster::{CamImage, Camera, ImageSize, NetImage, Network};
use crate::sample::Grid;
use crate::warp::{TpsBasis, Warp};

/// What the fit reports.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FitReport {
    /// Mean squared residual in linear projector light at the end, per value.
    pub final_loss: f64,
    /// Loss after each geometry iteration (all levels in order).
    pub loss_history: Vec<f64>,
    pub seconds: f64,
}

/// Fits a `linear` model on training pairs: captures `x̃_i` (camera space, already masked by the
/// FOV mask if desired) and projector inputs `x_i` (network space).
pub fn fit(
    captures: &[CamImage],
    targets: &[NetImage],
    init: Warp,
    settings: &FitSettings,
    mut progress: impl FnMut(&str, usize, usize),
) -> Result<(LinearModel, FitReport)> {
    let start = Instant::now();
    check_pairs(captures, targets)?;
    let cam_size = captures[0].size();
    let ImageSize {
        width: nw,
        height: nh,
    } = settings.network_size;
    let mut history = Vec::new();
    let (warp, curves) = fit_warp(
        captures,
        targets,
        init,
        settings,
        &mut history,
        &mut progress,
    );
    let mut grid = TpsBasis::new(nw, nh).grid(&warp);
    let mut refine = None;
    if let (true, Some((spacing, iters))) = (settings.learn_geometry, settings.refine) {
        let field = refine_geometry(
            captures,
            targets,
            &grid,
            &curves,
            settings,
            (spacing, iters),
            &mut history,
            &mut progress,
        );
        field.apply(&mut grid);
        refine = Some(field);
    }
    let (curves, coeffs, loss) = match settings.lattice {
        Some(lattice) if lattice != settings.network_size => {
            let fine = learned_grid(&warp, refine.as_ref(), settings.network_size, lattice);
            let up = lattice_targets(targets, lattice);
            let up = up.as_deref().unwrap_or(targets);
            fit_colour(captures, up, &fine, curves, settings.ridge)
        }
        _ => fit_colour(captures, targets, &grid, curves, settings.ridge),
    };
    progress("colour", 1, 1);
    Ok((
        LinearModel {
            geometry: Geometry::Learned(warp, refine),
            curves,
            coeffs,
            camera_size: cam_size,
            geometry_size: settings.network_size,
        },
        FitReport {
            final_loss: loss,
            loss_history: history,
            seconds: start.elapsed().as_secs_f64(),
        },
    ))
}

/// The affine + TPS geometry alone, as [`fit`] starts with (no dense refinement, no colour
/// model): what the CompenNet++ variants start their WarpingNet from. Inputs as for [`fit`].
pub fn fit_geometry(
    captures: &[CamImage],
    targets: &[NetImage],
    init: Warp,
    settings: &FitSettings,
) -> Result<Warp> {
    check_pairs(captures, targets)?;
    let (warp, _) = fit_warp(
        captures,
        targets,
        init,
        settings,
        &mut Vec::new(),
        |_, _, _| {},
    );
    Ok(warp)
}

/// Fits only the colour part on a fixed geometry (the two-step `linear-sl` baseline): the grid
/// maps network pixels to camera positions, e.g. from decoded structured light.
pub fn fit_on_grid(
    captures: &[CamImage],
    targets: &[NetImage],
    grid: Grid<Network, Camera>,
    settings: &FitSettings,
) -> Result<(LinearModel, FitReport)> {
    let start = Instant::now();
    check_pairs(captures, targets)?;
    if grid.width() < 2 || grid.height() < 2 {
        return Err(Error::Shape(format!(
            "grid is {}x{}, expected at least 2x2",
            grid.width(),
            grid.height()
        )));
    }
    // The grid's size is the model's lattice; finer than the projector images, they are
    // resampled onto it (see [`lattice_targets`]).
    let up = lattice_targets(targets, grid.size());
    let targets = up.as_deref().unwrap_or(targets);
    let (curves, coeffs, loss) =
        fit_colour(captures, targets, &grid, Curves::default(), settings.ridge);
    Ok((
        LinearModel {
            geometry_size: grid.size(),
            geometry: Geometry::Fixed(grid),
            curves,
            coeffs,
            camera_size: captures[0].size(),
        },
        FitReport {
            final_loss: loss,
            loss_history: Vec::new(),
            seconds: start.elapsed().as_secs_f64(),
        },
    ))
}

/// The projector images resampled onto a model lattice of `size` (`None` when they already
/// have that size). The projector shows an image stretched bilinearly over the canvas (half-pixel
/// centres), so a bilinear resample with the same convention gives, at each lattice pixel, close
/// to the value the projector showed there.
fn lattice_targets(targets: &[NetImage], size: ImageSize) -> Option<Vec<NetImage>> {
    (targets[0].size() != size).then(|| {
        targets
            .par_iter()
            .map(|t| crate::resize::resize_bilinear(t, size.width, size.height))
            .collect()
    })
}

/// Checks that captures and projector images pair up and are each of one size.
fn check_pairs(captures: &[CamImage], targets: &[NetImage]) -> Result<()> {
    if captures.is_empty() || captures.len() != targets.len() {
        return Err(Error::Input(format!(
            "linear fit needs as many captures as projector images, got {} and {}",
            captures.len(),
            targets.len()
        )));
    }
    let cam_size = captures[0].size();
    if let Some(c) = captures.iter().find(|c| c.size() != cam_size) {
        return Err(Error::Shape(format!(
            "captures differ in size: ({}, {}) and ({}, {})",
            cam_size.width,
            cam_size.height,
            c.size().width,
            c.size().height
        )));
    }
    let net_size = targets[0].size();
    if let Some(t) = targets.iter().find(|t| t.size() != net_size) {
        return Err(Error::Shape(format!(
            "projector images differ in size: ({}, {}) and ({}, {})",
            net_size.width,
            net_size.height,
            t.size().width,
            t.size().height
        )));
    }
    Ok(())
}
