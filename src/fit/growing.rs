//! A linear rung's fit on pairs that arrive one at a time, as a calibration's captures do: the
//! geometry and the response curves of the fit on the first pairs are kept, and each lattice
//! pixel's colour sums grow pair by pair ([`crate::linear::ColourSums`]), so that the fit on
//! every pair is one solve once the last has arrived. Once the first pairs are the geometry's
//! (24), that is the fit [`super::fit`] makes on all the pairs: a linear fit searches its
//! curves on those pairs too. Measured in docs/bench/calibrate.md ("The linear fit grown behind
//! the captures").

use std::ops::RangeInclusive;
use std::time::Instant;

use rayon::prelude::*;

use crate::dataset::Setup;
use crate::error::{Error, Result};
use crate::linear::{Coefficients, ColourSums, FitSettings, LinearModel};
use crate::model::store::ModelMeta;
use crate::model::{Kind, Model};
use crate::raster::{Camera, Levels, Mask, NetImage};

/// A linear rung's fit growing pair by pair from a model fitted on a setup's first pairs.
pub struct GrowingFit {
    /// The first fit's record, which the grown model's starts from.
    meta: ModelMeta,
    /// The projector FOV in camera space: captures are masked by it, as the fit masks them.
    fov: Mask<Camera>,
    /// The first fit's geometry and curves, which are the grown model's (no coefficients).
    first: LinearModel,
    /// The pairs the first fit's curves were searched on.
    curves_searched_on: usize,
    sums: ColourSums,
    /// Time spent adding pairs and solving, seconds.
    seconds: f64,
}

impl GrowingFit {
    /// Starts from `model`, a linear rung (`linear` or `linear-sl`) fitted on a setup's first
    /// pairs, with no pairs added yet. `None` for any other model, or one whose record does not
    /// hold the linear fit's settings (the ridge weight comes from there).
    pub fn new(model: &Model) -> Option<Self> {
        let Kind::Linear { model: linear, .. } = &model.kind else {
            return None;
        };
        let settings: FitSettings =
            serde_json::from_value(model.meta.training.settings.clone()).ok()?;
        let sums = ColourSums::new(linear.grid(), linear.curves, settings.ridge);
        Some(Self {
            meta: model.meta.clone(),
            fov: model.fov.clone(),
            // Its coefficients are replaced by the grown ones: not kept.
            first: LinearModel {
                coeffs: Coefficients {
                    width: 0,
                    height: 0,
                    data: Vec::new(),
                },
                geometry: linear.geometry.clone(),
                ..**linear
            },
            curves_searched_on: (model.meta.training.curves_searched_on)
                .unwrap_or(model.meta.training.ntrain),
            sums,
            seconds: 0.0,
        })
    }

    /// Pairs added so far.
    pub fn pairs(&self) -> usize {
        self.sums.pairs()
    }

    /// Adds the setup's training pairs `indices` (1-based, the next ones in order: the first
    /// add starts at pair 1), their captures masked by the model's FOV. Refused when they are
    /// not the next ones, or a capture or projector image is missing, unreadable or of another
    /// size (the error names the file).
    pub fn add(&mut self, setup: &Setup, indices: RangeInclusive<usize>) -> Result<()> {
        let next = self.pairs() + 1;
        if *indices.start() != next {
            return Err(Error::Input(format!(
                "a growing fit takes its pairs in order: pair {next} next, not {}",
                indices.start()
            )));
        }
        let t = Instant::now();
        let loaded: Vec<(Levels<Camera>, NetImage)> = indices
            .into_par_iter()
            .map(|i| -> Result<_> {
                let (capture, shown) = setup.load_train_pair(i)?;
                Ok((capture.into_masked(&self.fov)?, shown.into_space()))
            })
            .collect::<Result<_>>()?;
        let (captures, shown): (Vec<_>, Vec<_>) = loaded.into_iter().unzip();
        self.sums.add(&captures, &shown)?;
        let seconds = t.elapsed().as_secs_f64();
        tracing::debug!(
            "growing fit: pairs {}..={} added in {seconds:.2} s",
            next,
            next + captures.len() - 1
        );
        self.seconds += seconds;
        Ok(())
    }

    /// The model on every pair added: the first fit's geometry and curves, the coefficients
    /// solved on all pairs. Its record says how many pairs the curves were searched on
    /// (`training.curves_searched_on`). Fails when the solve diverged (no model).
    pub fn model(&self) -> Result<Model> {
        let t = Instant::now();
        let pairs = self.pairs();
        let (coeffs, loss) = self.sums.solve();
        if !loss.is_finite() {
            return Err(Error::Failed(format!(
                "the {} fit on {pairs} pairs diverged (final loss {loss}); no model produced",
                self.meta.method
            )));
        }
        let seconds = self.seconds + t.elapsed().as_secs_f64();
        let mut meta = self.meta.clone();
        meta.training.ntrain = pairs;
        meta.training.final_loss = Some(loss);
        meta.training.curves_searched_on = Some(self.curves_searched_on);
        meta.timings.fit_seconds = seconds;
        meta.timings.train_seconds = seconds;
        meta.weights_sha256 = None;
        let model = LinearModel {
            coeffs,
            ..self.first.clone()
        };
        Ok(Model::linear(meta, self.fov.clone(), model))
    }
}
