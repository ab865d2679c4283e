//! One row of `compend bench`: a method (or a reference row) on a scene, seed and training-set
//! size, with its cost and scores; the tables and the charts are drawn from these.

use compend::metrics::Scores;
use serde::Serialize;

/// One row of the benchmark.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub scene: String,
    pub seed: u64,
    /// A method, or a reference row: `uncompensated`, `geometry-only`, `oracle@network`, `oracle`.
    pub method: String,
    /// Sampling pairs.
    pub ntrain: Option<usize>,
    /// Closed-loop pairs trained on besides (`--loop-images`), if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub loop_pairs: Option<usize>,
    /// Training wall time, seconds (loading and FOV included).
    pub train_seconds: Option<f64>,
    /// Captures the method needs: training pairs, references, structured light.
    pub captures: Option<usize>,
    /// CPU reference compensation time per frame (camera image → network image), milliseconds.
    pub frame_ms_cpu: Option<f64>,
    /// Paper protocol on the test pairs (network space).
    pub paper: Option<Scores>,
    /// Closed loop on the rig inside the displayable area.
    pub closed_loop: Option<Scores>,
    /// Oracle PSNR minus this row's closed-loop PSNR, dB.
    pub gap_db: Option<f64>,
    /// Why the method produced no model (training failed or diverged), if it did not.
    pub failed: Option<String>,
    /// How the model it produced failed (diverged, collapsed, worse than uncompensated), if
    /// it did.
    pub failure: Option<compend::failure::Failure>,
    /// `auto`: the rung it chose.
    pub chosen: Option<String>,
    /// `auto` after a climb on the held-out pairs: the climbed rung and the best linear rung in
    /// closed loop on the rig's verification images, which decided between them.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub rig_check: Vec<compend::record::ClosedLoopScore>,
    /// `auto` with closed-loop pairs: its judgement of the residual rung on those held out.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub loop_held_out: Option<compend::record::LoopHeldOut>,
    /// `auto` with `--refresh-hz`: its climb's live pass against the display's frame budget.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub live: Option<compend::record::LiveCost>,
}

impl Row {
    pub(super) fn reference(scene: &str, seed: u64, method: &str, s: Scores, oracle: f64) -> Self {
        Row {
            scene: scene.into(),
            seed,
            method: method.into(),
            ntrain: None,
            loop_pairs: None,
            train_seconds: None,
            captures: None,
            frame_ms_cpu: None,
            paper: None,
            closed_loop: Some(s),
            gap_db: Some(oracle - s.psnr),
            failed: None,
            failure: None,
            chosen: None,
            rig_check: Vec::new(),
            loop_held_out: None,
            live: None,
        }
    }
}
