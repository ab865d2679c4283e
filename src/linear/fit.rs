//! Training entry points of the `linear` rung: the full fit ([`fit`]: geometry, then colour),
//! the geometry alone ([`fit_geometry`], for the CompenNet++ variants) and the colour alone on a
//! fixed grid ([`fit_on_grid`], for `linear-sl`), with their settings and report.
//!
//! Inputs: captures in camera space (camera pixels, encoded values in \[0,1\]) and the projector
//! images shown, in network space (network pixels).

use std::sync::Mutex;
use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::colour::fit_colour;
use super::geometry::{fit_warp, refine_geometry};
use super::model::{Curves, Geometry, LinearModel, learned_grid};
use super::settings::FitSettings;
use crate::error::{Error, Result};
use crate::raster::{Camera, ImageSize, NetImage, Network, ReadRgb};
use crate::sample::Grid;
use crate::warp::{OffsetField, TpsBasis, Warp};

/// What the fit reports.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FitReport {
    /// Mean squared residual in linear projector light at the end, per value.
    pub final_loss: f64,
    /// Loss after each geometry iteration (all levels in order).
    pub loss_history: Vec<f64>,
    pub seconds: f64,
    /// Whether the geometry came from a [`GeometryMemo`] rather than a fit of its own.
    #[serde(default)]
    pub geometry_reused: bool,
}

/// Fits a `linear` model on training pairs: captures `x̃_i` (camera space, already masked by the
/// FOV mask if desired) and projector inputs `x_i` (network space).
pub fn fit<C: ReadRgb<Camera>>(
    captures: &[C],
    targets: &[NetImage],
    init: Warp,
    settings: &FitSettings,
    progress: impl FnMut(&str, usize, usize),
) -> Result<(LinearModel, FitReport)> {
    fit_with_memo(captures, targets, init, settings, None, progress)
}

/// [`fit`], taking its geometry from `memo` when the memo's last geometry was fitted on the
/// same things ([`GeometryMemo`]), and leaving its own there otherwise.
pub fn fit_with_memo<C: ReadRgb<Camera>>(
    captures: &[C],
    targets: &[NetImage],
    init: Warp,
    settings: &FitSettings,
    memo: Option<&GeometryMemo>,
    mut progress: impl FnMut(&str, usize, usize),
) -> Result<(LinearModel, FitReport)> {
    let start = Instant::now();
    check_pairs(captures, targets)?;
    let cam_size = captures[0].dimensions();
    let key = memo.and_then(|_| geometry_key(captures, targets, &init, settings));
    let remembered = memo.zip(key).and_then(|(m, k)| m.get(k));
    let geometry_reused = remembered.is_some();
    let geometry = match remembered {
        Some(g) => {
            tracing::info!(
                "linear fit on {} pairs: the geometry fitted on the same first {} pairs reused \
                 ({:.1} s saved)",
                captures.len(),
                g.images,
                g.seconds
            );
            g
        }
        None => {
            let g = fit_learned_geometry(captures, targets, init, settings, key, &mut progress);
            if let Some(m) = memo {
                m.put(g.clone());
            }
            g
        }
    };
    let colour_start = Instant::now();
    let (curves, coeffs, loss) = match settings.lattice {
        Some(lattice) if lattice != settings.network_size => {
            let fine = learned_grid(
                &geometry.warp,
                geometry.refine.as_ref(),
                settings.network_size,
                lattice,
            );
            fit_colour(
                captures,
                targets,
                &fine,
                geometry.curves,
                settings.ridge,
                (settings.geometry_images, settings.colour),
            )
        }
        _ => {
            let grid = geometry.grid(settings.network_size);
            fit_colour(
                captures,
                targets,
                &grid,
                geometry.curves,
                settings.ridge,
                (settings.geometry_images, settings.colour),
            )
        }
    };
    progress("colour", 1, 1);
    let seconds = start.elapsed().as_secs_f64();
    tracing::debug!(
        "linear fit on {} pairs: geometry {:.1} s (on the first {}), colour {:.1} s",
        captures.len(),
        colour_start.duration_since(start).as_secs_f64(),
        geometry.images,
        colour_start.elapsed().as_secs_f64()
    );
    Ok((
        LinearModel {
            geometry: Geometry::Learned(geometry.warp, geometry.refine),
            curves,
            coeffs,
            camera_size: cam_size,
            geometry_size: settings.network_size,
        },
        FitReport {
            final_loss: loss,
            loss_history: geometry.history,
            seconds,
            geometry_reused,
        },
    ))
}

/// Fits the geometry that [`fit_with_memo`] on pairs starting with these would fit, and leaves
/// it in `memo` for that fit to take (nothing to do when the memo already holds it). Inputs as
/// for [`fit`]; only the first `settings.geometry_images` pairs are used.
pub fn prefit_geometry<C: ReadRgb<Camera>>(
    captures: &[C],
    targets: &[NetImage],
    init: Warp,
    settings: &FitSettings,
    memo: &GeometryMemo,
) -> Result<()> {
    check_pairs(captures, targets)?;
    let key = geometry_key(captures, targets, &init, settings);
    if key.is_some_and(|k| memo.get(k).is_some()) {
        return Ok(());
    }
    let g = fit_learned_geometry(captures, targets, init, settings, key, &mut |_, _, _| {});
    tracing::info!(
        "linear geometry fitted ahead on the first {} pairs in {:.1} s",
        g.images,
        g.seconds
    );
    memo.put(g);
    Ok(())
}

/// The geometry stage of a [`fit`]: the affine + TPS warp, its dense refinement and the coarse
/// response curves the colour solve starts from. It depends only on the first
/// `settings.geometry_images` pairs, the initial warp and the settings other than the lattice.
#[derive(Clone, Debug)]
struct FittedGeometry {
    warp: Warp,
    refine: Option<OffsetField>,
    curves: Curves,
    /// Loss after each geometry iteration (all levels in order).
    history: Vec<f64>,
    /// The pairs it was fitted on (the first ones).
    images: usize,
    /// What it was fitted on ([`geometry_key`]); `None` when not computed.
    key: Option<u64>,
    seconds: f64,
}

impl FittedGeometry {
    /// The affine + TPS grid with the refinement applied, at `size` (network pixels → camera
    /// coordinates).
    fn grid(&self, size: ImageSize) -> Grid<Network, Camera> {
        let mut grid = TpsBasis::new(size.width, size.height).grid(&self.warp);
        if let Some(field) = &self.refine {
            field.apply(&mut grid);
        }
        grid
    }
}

/// The last geometry a [`fit_with_memo`] fitted, for the fits of one training or calibration to
/// share. Those fits see the same first pairs (the sampling pairs; held-out and closed-loop
/// pairs come after them) and the geometry uses only the first `geometry_images` of them, so
/// it comes out the same each time: at the virtual rig's sizes about 4 s of every fit on 2
/// cores (release build), done once. A fit takes the memo's geometry only when a fingerprint of what the
/// geometry depends on matches ([`geometry_key`]); otherwise it fits its own and leaves it
/// there.
#[derive(Debug, Default)]
pub struct GeometryMemo(Mutex<Option<FittedGeometry>>);

impl GeometryMemo {
    fn get(&self, key: u64) -> Option<FittedGeometry> {
        let last = self.0.lock().unwrap_or_else(|e| e.into_inner());
        last.as_ref().filter(|g| g.key == Some(key)).cloned()
    }

    fn put(&self, geometry: FittedGeometry) {
        *self.0.lock().unwrap_or_else(|e| e.into_inner()) = Some(geometry);
    }
}

/// A fingerprint of what a fit's geometry depends on: the first `geometry_images` captures and
/// projector images (sizes and values), the initial warp, and the settings but the lattice.
/// `None` if the settings cannot be written out (then nothing is shared).
fn geometry_key<C: ReadRgb<Camera>>(
    captures: &[C],
    targets: &[NetImage],
    init: &Warp,
    settings: &FitSettings,
) -> Option<u64> {
    use std::hash::{DefaultHasher, Hash, Hasher};
    let ng = settings.geometry_images.clamp(1, captures.len());
    let geometry_settings = FitSettings {
        lattice: None,
        ..settings.clone()
    };
    let written = serde_json::to_vec(&geometry_settings).ok()?;
    // One hash per image, in parallel, then the hashes in order.
    fn image<S: crate::raster::Space>(img: &impl ReadRgb<S>) -> u64 {
        let mut h = DefaultHasher::new();
        img.hash_values(&mut h);
        h.finish()
    }
    let images: Vec<u64> = (captures[..ng].par_iter())
        .map(image)
        .chain(targets[..ng].par_iter().map(image))
        .collect();
    let mut h = DefaultHasher::new();
    (ng, images, written).hash(&mut h);
    let params: Vec<u32> = init.to_params().iter().map(|v| v.to_bits()).collect();
    params.hash(&mut h);
    Some(h.finish())
}

/// The geometry stage of [`fit`] on the pairs' first `settings.geometry_images`.
fn fit_learned_geometry<C: ReadRgb<Camera>>(
    captures: &[C],
    targets: &[NetImage],
    init: Warp,
    settings: &FitSettings,
    key: Option<u64>,
    progress: &mut impl FnMut(&str, usize, usize),
) -> FittedGeometry {
    let start = Instant::now();
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
        &mut *progress,
    );
    let mut refine = None;
    tracing::debug!("affine + TPS in {:.2} s", start.elapsed().as_secs_f64());
    if let (true, Some((spacing, iters))) = (settings.learn_geometry, settings.refine) {
        let grid = TpsBasis::new(nw, nh).grid(&warp);
        refine = Some(refine_geometry(
            captures,
            targets,
            &grid,
            &curves,
            settings,
            (spacing, iters),
            &mut history,
            progress,
        ));
    }
    FittedGeometry {
        warp,
        refine,
        curves,
        history,
        images: settings.geometry_images.clamp(1, captures.len()),
        key,
        seconds: start.elapsed().as_secs_f64(),
    }
}

/// The affine + TPS geometry alone, as [`fit`] starts with (no dense refinement, no colour
/// model): what the CompenNet++ variants start their WarpingNet from. Inputs as for [`fit`].
pub fn fit_geometry<C: ReadRgb<Camera>>(
    captures: &[C],
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
pub fn fit_on_grid<C: ReadRgb<Camera>>(
    captures: &[C],
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
    // resampled onto it (see [`fit_colour`]).
    let (curves, coeffs, loss) = fit_colour(
        captures,
        targets,
        &grid,
        Curves::default(),
        settings.ridge,
        (settings.geometry_images, settings.colour),
    );
    Ok((
        LinearModel {
            geometry_size: grid.size(),
            geometry: Geometry::Fixed(grid),
            curves,
            coeffs,
            camera_size: captures[0].dimensions(),
        },
        FitReport {
            final_loss: loss,
            loss_history: Vec::new(),
            seconds: start.elapsed().as_secs_f64(),
            geometry_reused: false,
        },
    ))
}

/// Checks that captures and projector images pair up and are each of one size.
fn check_pairs<C: ReadRgb<Camera>>(captures: &[C], targets: &[NetImage]) -> Result<()> {
    if captures.is_empty() || captures.len() != targets.len() {
        return Err(Error::Input(format!(
            "linear fit needs as many captures as projector images, got {} and {}",
            captures.len(),
            targets.len()
        )));
    }
    let cam_size = captures[0].dimensions();
    if let Some(c) = captures.iter().find(|c| c.dimensions() != cam_size) {
        return Err(Error::Shape(format!(
            "captures differ in size: ({}, {}) and ({}, {})",
            cam_size.width,
            cam_size.height,
            c.dimensions().width,
            c.dimensions().height
        )));
    }
    let net_size = targets[0].size();
    if [cam_size, net_size]
        .iter()
        .any(|s| s.width == 0 || s.height == 0)
    {
        return Err(Error::Shape(format!(
            "linear fit needs captures and projector images of at least 1x1 pixels, got {} and {}",
            cam_size, net_size
        )));
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::CamImage;

    /// Images with no pixels are refused with an error that names the sizes, not a panic.
    #[test]
    fn empty_images_are_refused() {
        let caps = vec![CamImage::new(0, 0); 4];
        let tgts = vec![NetImage::new(8, 8); 4];
        let settings = FitSettings::default();
        let init = Warp::from_affine([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        let err = fit(&caps, &tgts, init, &settings, |_, _, _| {}).expect_err("refused");
        assert!(err.to_string().contains("at least 1x1 pixels"), "{err}");
        assert!(err.to_string().contains("0x0"), "{err}");
    }
}
