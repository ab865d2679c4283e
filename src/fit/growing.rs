//! A linear rung's fit on pairs that arrive one at a time, as a calibration's closed-loop pairs
//! do: the geometry and the response curves of the fit on the first pairs are kept, and each
//! lattice pixel's colour sums grow pair by pair ([`crate::linear::ColourSums`]), so that the
//! fit on every pair is one solve once the last has arrived. Measured in docs/bench/calibrate.md
//! ("The fit on every pair, grown during the captures").

use std::ops::RangeInclusive;
use std::time::Instant;

use rayon::prelude::*;

use crate::dataset::Setup;
use crate::error::{Error, Result};
use crate::linear::{ColourSums, FitSettings, LinearModel};
use crate::model::store::ModelMeta;
use crate::model::{Kind, Model};
use crate::raster::{Camera, Levels, Mask, NetImage};

/// A linear rung's fit growing pair by pair from a model fitted on a setup's first pairs.
pub struct GrowingFit {
    /// The first fit's record, which the grown model's starts from.
    meta: ModelMeta,
    /// The projector FOV in camera space: captures are masked by it, as the fit masks them.
    fov: Mask<Camera>,
    /// The first fit: its geometry and curves are the grown model's.
    first: LinearModel,
    /// The pairs the first fit was fitted on (its curves were searched on them).
    first_pairs: usize,
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
            first: (**linear).clone(),
            first_pairs: model.meta.training.ntrain,
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
        self.seconds += t.elapsed().as_secs_f64();
        Ok(())
    }

    /// The model on every pair added: the first fit's geometry and curves, the coefficients
    /// solved on all pairs. Its record says how many pairs the curves were searched on
    /// (`training.curves_searched_on`). Fails when the solve diverged (no model).
    pub fn finish(self) -> Result<Model> {
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
        let mut meta = self.meta;
        meta.training.ntrain = pairs;
        meta.training.final_loss = Some(loss);
        meta.training.curves_searched_on = Some(self.first_pairs);
        meta.timings.fit_seconds = seconds;
        meta.timings.train_seconds = seconds;
        meta.weights_sha256 = None;
        let model = LinearModel {
            coeffs,
            ..self.first
        };
        Ok(Model::linear(meta, self.fov, model))
    }
}
