//! `--method auto`: the ladder climbed only as far as the scene needs (docs/architecture.md,
//! "Models").
//!
//! 1. The linear rungs (`linear`, and `linear-sl` when the setup has structured light) are
//!    fitted on the sampling pairs but the last sixth (at least 4) and scored on those with the
//!    paper protocol; the best is the rung to beat. Closed-loop pairs at the end of the data
//!    (`calibrate` takes them after the sampling pairs) are not sampling pairs.
//! 2. The CompenNet++ rung the machine can afford ([`climb_rung`]: `compennet++-res`, `linear`
//!    plus a CPU-sized correction, on the CPU; the full `compennet++` on a GPU) is trained and
//!    judged:
//!    - `compennet++-res` on a setup with enough closed-loop pairs ([`judges_on_loop_pairs`]):
//!      trained on every pair but the last sixth of the closed-loop ones (at least 4), and
//!      judged on those: how much closer than `linear`'s its compensations of their desired
//!      views come to the projector images that move their captures towards the views
//!      ([`LoopHeldOut`]). That is what its correction learns and what closed loop asks; on
//!      sampling captures a network gains from averaging capture noise away, which closed loop
//!      does not repay. In projector pixels the figure overstates the camera's gain where the
//!      surface is dark, so the rig's check stays (docs/bench/ladder.md);
//!    - otherwise on the sampling pairs the linear rungs were fitted on, scored as they were.
//!
//!    It is kept only if it beats the rung below by the climbing rule's margin ([`ClimbRule`]);
//!    the service's progressive calibration applies the same rule to a calibration's test
//!    pairs, and `calibrate` confirms a climb on the rig ([`settle_climb`]).
//! 3. A kept CompenNet++ rung is the model as trained (training it again on every pair would
//!    double the dearest step). Otherwise the best linear rung is fitted again on every pair,
//!    closed-loop ones included, which costs seconds.
//!
//! The rule, every candidate's held-out figures and the time each took go into `model.json`
//! (`training.auto`).

use std::time::Instant;

use super::{MIN_TRAIN, Request, Summary, TrainDevice, TrainingData, compennet, linear_rungs};
use crate::dataset::{Reference, Setup};
use crate::error::Result;
use crate::model::store::{AutoCandidate, AutoEvidence, ClosedLoopScore, LoopHeldOut};
use crate::model::{Method, MethodChoice, Model};

/// When a rung replaces the one below it: its PSNR on pairs neither was trained on must beat
/// the lower rung's by `gain_db`. The margin pays for the dearer rung's cost (training time,
/// a frame pass several times slower) and sits above the spread of held-out scores between
/// seeds of the same rung.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClimbRule {
    /// Required gain in PSNR, dB.
    pub gain_db: f64,
}

impl Default for ClimbRule {
    fn default() -> Self {
        Self {
            gain_db: DEFAULT_CLIMB_GAIN_DB,
        }
    }
}

/// The default margin of [`ClimbRule`], dB.
pub const DEFAULT_CLIMB_GAIN_DB: f64 = 0.5;

impl ClimbRule {
    /// Whether a rung scoring `upper_psnr` replaces one scoring `lower_psnr` (dB, the same
    /// pairs). A score that is not a number never climbs.
    pub fn climbs(&self, upper_psnr: f64, lower_psnr: f64) -> bool {
        upper_psnr.is_finite() && upper_psnr - lower_psnr >= self.gain_db
    }

    /// The rule in words, for records and output.
    pub fn describe(&self, on: &str) -> String {
        format!(
            "the best linear rung on {on}, replaced by the CompenNet++ rung the machine can \
             afford only if that one's paper-protocol PSNR is at least {} dB higher{}",
            self.gain_db,
            if self.gain_db < 0.0 {
                " (a negative margin: a rung that scores lower can be kept)"
            } else {
                ""
            }
        )
    }

    /// A warning for a margin below zero, which lets a climb keep a rung that scores lower
    /// than the one below it (tests use it to force a climb); `None` otherwise. `name`: the
    /// flag or key that set it.
    pub fn caveat(&self, name: &str) -> Option<String> {
        (self.gain_db < 0.0).then(|| {
            format!(
                "{name} {}: a negative margin keeps a climbed rung that scores up to {} dB lower \
                 than the rung below it",
                self.gain_db, -self.gain_db
            )
        })
    }

    /// The rule in words when the climb is judged on held-out closed-loop pairs
    /// ([`crate::model::store::LoopHeldOut`]).
    pub fn describe_on_loop_pairs(&self, rung: Method) -> String {
        format!(
            "the best linear rung on held-out sampling pairs (paper protocol), replaced by {rung} \
             only if, on closed-loop pairs held out of its training, its compensations of the \
             desired views come at least {} dB closer (PSNR) than `linear`'s to the projector \
             images that move the captures towards those views{}",
            self.gain_db,
            if self.gain_db < 0.0 {
                " (a negative margin: a rung that scores lower can be kept)"
            } else {
                ""
            }
        )
    }

    /// Whether a climb judged while its rung trains can stop early, its margin out of reach.
    /// `gains`: (iteration, the rung's held-out PSNR minus the lower rung's, dB) at each
    /// checkpoint so far, the first at iteration 0; `total`: the planned iterations.
    ///
    /// The residual rung's gain grows along an S: slowly at first (its correction starts at
    /// zero and Adam's steps are small), fastest in the middle, then ever more slowly as it
    /// settles, and more slowly still after the lr step. Once its rise has slowed (the last
    /// interval rose no faster than the one before), the straight line through the last
    /// interval, carried on to `total`, ends above where the training would; the training
    /// stops when that line stays below the margin (a gain that fell carries no rise on). Before
    /// the rise slows the line can end below the final gain (on the dark texture, seed 47, the
    /// first tenth rose 0.09 dB of an eventual 1.4), so it never stops there. The curves
    /// measured are in docs/bench/ladder.md. A gain that is not a number stops the training;
    /// the last iteration never does (the judgement itself decides there).
    pub fn out_of_reach(&self, gains: &[(usize, f64)], total: usize) -> bool {
        if gains.iter().any(|(_, g)| !g.is_finite()) {
            return true;
        }
        let [.., (i0, g0), (i1, g1), (i2, g2)] = gains else {
            return false;
        };
        if *i2 >= total || i2 <= i1 || i1 <= i0 {
            return false;
        }
        let before = (g1 - g0) / (i1 - i0) as f64;
        let rate = (g2 - g1) / (i2 - i1) as f64;
        if rate > before {
            return false;
        }
        g2 + rate.max(0.0) * ((total - i2) as f64) < self.gain_db
    }

    /// `rule`, the rule of the held-out comparison in words, followed by the rig's
    /// confirmation ([`ClimbRule::confirms`]).
    pub fn describe_on_rig(&self, rule: &str) -> String {
        format!(
            "{rule}, and then, on the rig, only if its closed-loop PSNR on the verification \
             images is also at least {} dB higher",
            self.gain_db
        )
    }

    /// The closed-loop confirmation of a climb on the rig: whether the climbed rung (`upper`)
    /// is kept over the lower one, from each one's verification (PSNR in dB of the captured
    /// projection, and whether it would be installed on its own). A rung that would not be
    /// installed never wins; between two installable ones the margin decides, as on the
    /// held-out pairs. Capture noise favours a network on held-out captures (it averages the
    /// noise of its input away) but not in closed loop, where the input is the noise-free
    /// desired image: the rig decides what the viewer sees (docs/bench/ladder.md).
    pub fn confirms(&self, upper: (f64, bool), lower: (f64, bool)) -> bool {
        match (upper.1, lower.1) {
            (false, _) => false,
            (true, false) => true,
            (true, true) => self.climbs(upper.0, lower.0),
        }
    }
}

/// The CompenNet++ rung a training device can afford: on the CPU the residual rung (`linear`
/// plus a CPU-sized CompenNet correction, which starts where `linear` ends), the full one on a
/// GPU.
pub fn climb_rung(device: TrainDevice) -> Method {
    match device {
        TrainDevice::Cpu => Method::CompenNetPpRes,
        TrainDevice::Cuda(_) => Method::CompenNetPp,
    }
}

/// Pairs held out of `n` for `auto`'s comparisons: the last sixth, at least 4.
fn held_out(n: usize) -> usize {
    (n / 6).max(4)
}

/// Whether `auto` judges its climb on `loops` closed-loop pairs (the residual rung; see
/// [`fit_auto`]): enough to hold [`held_out`] of them out and train the correction on at least
/// [`MIN_TRAIN`] others.
pub fn judges_on_loop_pairs(loops: usize) -> bool {
    loops >= held_out(loops) + MIN_TRAIN
}

/// How many of the last training pairs of `n` are closed-loop pairs (a desired view in
/// `cam/desire/train`), counted back from the last until one is not.
fn trailing_loop_pairs(setup: &Setup, n: usize) -> Result<usize> {
    let loops = setup.loop_pairs(n)?;
    Ok(loops
        .iter()
        .rev()
        .zip((1..=n).rev())
        .take_while(|(a, b)| **a == *b)
        .count())
}

/// `--method auto` on loaded training data (see the module documentation).
pub(super) fn fit_auto(
    setup: &Setup,
    req: &Request,
    ntrain: usize,
    data: TrainingData,
    start: Instant,
    mut progress: impl FnMut(&str, usize, usize),
) -> Result<(Model, Summary)> {
    let rule = ClimbRule {
        gain_db: req.climb_gain_db.unwrap_or(DEFAULT_CLIMB_GAIN_DB),
    };
    let n = data.captures.len();
    let rung = climb_rung(req.device);
    let variant = crate::nn::compennetpp::Variant::from_method(rung.name());
    // Closed-loop pairs at the end of the data: the linear rungs compare on the sampling pairs
    // before them, and the residual rung, whose correction trains on them, is judged on some
    // of them held out.
    let loops = trailing_loop_pairs(setup, n)?;
    let sampling = n - loops;
    let on_loop_pairs = variant.is_some_and(|v| v.residual()) && judges_on_loop_pairs(loops);
    let held = held_out(sampling);
    if sampling < held + MIN_TRAIN {
        let evidence = AutoEvidence {
            rule: rule.describe("held-out training pairs"),
            chosen: Method::Linear,
            why: Some(format!(
                "{sampling} sampling pairs are too few to hold {held} out: `linear` without \
                 comparison"
            )),
            held_out: None,
            fitted_on: None,
            required_gain_db: Some(rule.gain_db),
            candidates: Vec::new(),
            closed_loop: Vec::new(),
            loop_held_out: None,
        };
        return linear_rungs::fit_linear(
            setup,
            req,
            Method::Linear,
            Some(evidence),
            ntrain,
            data,
            start,
            progress,
        );
    }
    let cut = sampling - held;
    let (fit_pairs, held_pairs) = (
        (&data.captures[..cut], &data.targets[..cut]),
        (&data.captures[cut..sampling], &data.targets[cut..sampling]),
    );
    let mut candidates = linear_rungs::score_linear_rungs(
        setup,
        req,
        fit_pairs,
        held_pairs,
        data.theta,
        &mut progress,
    )?;
    let best_linear = candidates
        .iter()
        .max_by(|a, b| a.held_out_psnr.total_cmp(&b.held_out_psnr))
        .map_or((Method::Linear, f64::NAN), |c| (c.method, c.held_out_psnr));

    let mut why = None;
    let mut climbed = None;
    let mut loop_held_out = None;
    if req.climb_later {
        why = Some(format!(
            "{rung} is judged later, on the closed-loop pairs taken with the linear rung"
        ));
    } else if !setup.reference_path(Reference::Gray).is_file() {
        why = Some(format!(
            "no gray surface capture ({}): {rung} cannot be trained",
            setup.reference_path(Reference::Gray).display()
        ));
    } else if let Some(variant) = variant {
        let t0 = Instant::now();
        let (model, summary, upper, lower) = if on_loop_pairs {
            let (model, summary, judged) =
                train_judged(setup, req, variant, &data, loops, rule, &mut progress)?;
            let psnr = |i: usize| judged.scores.get(i).map_or(f64::NAN, |c| c.held_out_psnr);
            let (up, lin) = (psnr(1), psnr(0));
            loop_held_out = Some(judged);
            (model, summary, up, lin)
        } else {
            // The rung trains on the sampling pairs the linear rungs were fitted on.
            let sub_req = Request {
                method: MethodChoice::Rung(rung),
                ntrain: Some(cut),
                lattice: req.lattice.filter(|_| variant.residual()),
                ..req.clone()
            };
            let (model, summary, _) = compennet::train_compennet(
                setup,
                &sub_req,
                (rung, variant),
                data.first(cut),
                None,
                t0,
                &mut progress,
            )?;
            let mut acc = crate::metrics::Accumulator::default();
            for (c, t) in held_pairs.0.iter().zip(held_pairs.1) {
                acc.add(&crate::model::at_size(model.infer(c)?, t.size()), t)?;
            }
            let scores = acc.finish()?;
            candidates.push(AutoCandidate {
                method: rung,
                held_out_psnr: scores.psnr,
                held_out_ssim: scores.ssim,
                fit_seconds: t0.elapsed().as_secs_f64(),
            });
            tracing::info!(
                "auto: {rung} {:.2} dB against {} {:.2} dB on {held} held-out pairs (climbs \
                     at {:+} dB)",
                scores.psnr,
                best_linear.0,
                best_linear.1,
                rule.gain_db
            );
            (model, summary, scores.psnr, best_linear.1)
        };
        if rule.climbs(upper, lower) {
            climbed = Some((model, summary));
        }
    }
    let chosen = climbed
        .as_ref()
        .map_or(best_linear.0, |(m, _)| m.meta.method);
    let evidence = AutoEvidence {
        rule: if loop_held_out.is_some() {
            rule.describe_on_loop_pairs(rung)
        } else {
            rule.describe("held-out training pairs")
        },
        chosen,
        why,
        held_out: Some(held),
        fitted_on: Some(cut),
        required_gain_db: Some(rule.gain_db),
        candidates,
        closed_loop: Vec::new(),
        loop_held_out,
    };
    match climbed {
        Some((mut model, summary)) => {
            model.meta.training.auto = Some(evidence);
            let seconds = start.elapsed().as_secs_f64();
            model.meta.timings.train_seconds = seconds;
            Ok((model, Summary { seconds, ..summary }))
        }
        None => linear_rungs::fit_linear(
            setup,
            req,
            best_linear.0,
            Some(evidence),
            ntrain,
            data,
            start,
            progress,
        ),
    }
}

/// `compennet++-res` (`variant`) trained on every pair of `data` but the last sixth of its
/// `loops` trailing closed-loop pairs, and judged on those as it trains ([`compennet::Judge`]):
/// its training stops early when it cannot reach `rule`'s margin. `req` has its lattice
/// resolved. Returns the model, its summary and the judgement.
fn train_judged(
    setup: &Setup,
    req: &Request,
    variant: crate::nn::compennetpp::Variant,
    data: &TrainingData,
    loops: usize,
    rule: ClimbRule,
    progress: impl FnMut(&str, usize, usize),
) -> Result<(Model, Summary, LoopHeldOut)> {
    let rung = Method::CompenNetPpRes;
    let n = data.captures.len();
    let h = held_out(loops);
    let indices: Vec<usize> = (n - h + 1..=n).collect();
    // A damaged held-out desired view fails now, not after the training.
    setup.load_loop_desired(&indices)?;
    let sub_req = Request {
        method: MethodChoice::Rung(rung),
        ntrain: Some(n - h),
        ..req.clone()
    };
    let judge = compennet::Judge {
        indices,
        captures: &data.captures,
        targets: &data.targets,
        rule,
    };
    let (model, summary, judged) = compennet::train_compennet(
        setup,
        &sub_req,
        (rung, variant),
        data.first(n - h),
        Some(judge),
        Instant::now(),
        progress,
    )?;
    let judged = judged.ok_or_else(|| {
        crate::error::Error::Failed(format!("{rung}: its training returned no judgement"))
    })?;
    let (lin, up) = (&judged.scores[0], &judged.scores[1]);
    tracing::info!(
        "auto: {rung} {:.2} dB against linear {:.2} dB on {h} held-out closed-loop pairs \
         (climbs at {:+} dB){}",
        up.held_out_psnr,
        lin.held_out_psnr,
        rule.gain_db,
        judged.stopped_at.map_or(String::new(), |i| format!(
            "; its training stopped at iteration {i} of {}",
            judged.iterations
        ))
    );
    Ok((model, summary, judged))
}

/// `compennet++-res` (`req` asks for it) trained and judged as `auto` judges its climb on a
/// setup with closed-loop pairs (see the module documentation): on every pair but the last
/// sixth of the closed-loop ones, then on those against its own linear part; its training
/// stops early when it cannot reach `rule`'s margin. For the service's progressive
/// calibration, which climbs by `auto`'s rule. `None` when the request is another rung or the
/// setup has too few closed-loop pairs ([`judges_on_loop_pairs`]).
pub fn judge_on_loop_pairs(
    setup: &Setup,
    req: &Request,
    rule: ClimbRule,
    progress: impl FnMut(&str, usize, usize),
) -> Result<Option<(Model, LoopHeldOut)>> {
    let rung = Method::CompenNetPpRes;
    let Some(variant) = crate::nn::compennetpp::Variant::from_method(rung.name()) else {
        return Ok(None);
    };
    if req.method != MethodChoice::Rung(rung) {
        return Ok(None);
    }
    super::check_request(req, Some(variant))?;
    let every = Request {
        ntrain: None,
        ..super::with_lattice(setup, req, Some(variant))?
    };
    let n = super::train_count(setup, &every, Some(variant))?;
    let loops = trailing_loop_pairs(setup, n)?;
    if !judges_on_loop_pairs(loops) {
        return Ok(None);
    }
    let data = super::load_training(setup, false, n)?;
    let (model, _, judged) = train_judged(setup, &every, variant, &data, loops, rule, progress)?;
    Ok(Some((model, judged)))
}

/// After `auto` climbed (`climbed` is a CompenNet++ rung with `auto`'s evidence): its best
/// linear candidate fitted on every pair of the request, for the rig to compare with the climbed
/// rung in closed loop ([`settle_climb`]), carrying the same evidence. `None` when `climbed`
/// did not climb (a linear rung, or no evidence).
pub fn lower_rung(
    setup: &Setup,
    req: &Request,
    climbed: &Model,
    progress: impl FnMut(&str, usize, usize),
) -> Result<Option<Model>> {
    let Some(evidence) = climbed
        .meta
        .training
        .auto
        .as_ref()
        .filter(|_| !climbed.meta.method.is_linear())
    else {
        return Ok(None);
    };
    let Some(lower) = evidence.best_linear() else {
        return Ok(None);
    };
    tracing::info!(
        "auto: fitting {} for the rig to compare with {} in closed loop",
        lower.method,
        climbed.meta.method
    );
    let req = Request {
        method: MethodChoice::Rung(lower.method),
        climb_gain_db: None,
        climb_later: false,
        iters: None,
        batch: None,
        ..req.clone()
    };
    let (mut model, _) = super::fit(setup, &req, progress)?;
    model.meta.training.auto = Some(evidence.clone());
    Ok(Some(model))
}

/// The rig's verdict on a climb ([`ClimbRule::confirms`]): the climbed rung (`upper`) or the
/// linear rung fitted beside it (`lower`, [`lower_rung`]), each with its closed-loop score on
/// the same verification images. Returns the model kept, with both scores, the choice and the
/// rule in its `training.auto`, and whether it is the climbed one.
pub fn settle_climb(
    upper: (Model, ClosedLoopScore),
    lower: (Model, ClosedLoopScore),
    rule: ClimbRule,
) -> (Model, bool) {
    let kept = rule.confirms(
        (upper.1.psnr, upper.1.passed),
        (lower.1.psnr, lower.1.passed),
    );
    tracing::info!(
        "auto: {} {:.2} dB against {} {:.2} dB in closed loop (climbs at {:+} dB): {} kept",
        upper.1.method,
        upper.1.psnr,
        lower.1.method,
        lower.1.psnr,
        rule.gain_db,
        if kept { upper.1.method } else { lower.1.method }
    );
    let scores = vec![upper.1, lower.1];
    let mut model = if kept { upper.0 } else { lower.0 };
    let chosen = model.meta.method;
    if let Some(evidence) = model.meta.training.auto.as_mut() {
        evidence.chosen = chosen;
        evidence.closed_loop = scores;
        evidence.rule = rule.describe_on_rig(&evidence.rule);
    }
    (model, kept)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rung_climbs_only_past_the_margin_and_never_on_a_non_number() {
        let rule = ClimbRule { gain_db: 0.5 };
        assert!(rule.climbs(25.5, 25.0));
        assert!(!rule.climbs(25.49, 25.0));
        assert!(!rule.climbs(f64::NAN, 25.0));
        assert!(!rule.climbs(f64::INFINITY, 25.0));
        // Nor against a lower rung with no score: nothing to compare with.
        assert!(!rule.climbs(20.0, f64::NAN));
        assert_eq!(climb_rung(TrainDevice::Cpu), Method::CompenNetPpRes);
        assert_eq!(climb_rung(TrainDevice::Cuda(0)), Method::CompenNetPp);
        assert_eq!(held_out(48), 8);
        assert_eq!(held_out(12), 4);
        // Closed-loop pairs judge a climb when 4 can be held out and 4 trained on.
        assert!(!judges_on_loop_pairs(0));
        assert!(!judges_on_loop_pairs(7));
        assert!(judges_on_loop_pairs(8));
        assert!(judges_on_loop_pairs(48));
    }

    #[test]
    fn a_judged_training_stops_only_when_its_gain_has_slowed_below_reach_of_the_margin() {
        let rule = ClimbRule { gain_db: 0.5 };
        // One interval: its rate cannot show the rise slowing.
        assert!(!rule.out_of_reach(&[(0, 0.0), (100, 0.02)], 1000));
        // Rising ever faster (the start of the S): never stops, however small the gain.
        assert!(!rule.out_of_reach(&[(0, 0.0), (100, 0.01), (200, 0.03)], 1000));
        // Slowed, and 0.1 dB per 100 iterations carried on reaches 1.0 dB: in reach.
        assert!(!rule.out_of_reach(&[(0, 0.0), (100, 0.1), (200, 0.2)], 1000));
        // Slowed to 0.01 dB per 100: 0.39 dB by the end at that rate, out of reach.
        assert!(rule.out_of_reach(&[(0, 0.0), (100, 0.3), (200, 0.31)], 1000));
        // Only the last two intervals count.
        assert!(rule.out_of_reach(&[(0, 0.0), (100, 0.01), (200, 0.05), (300, 0.06)], 1000));
        // Falling: no rise is carried on.
        assert!(rule.out_of_reach(&[(0, 0.0), (100, 0.4), (200, 0.3)], 1000));
        // Not at the end, nor on a negative margin the gain already reaches; a gain that is
        // not a number stops.
        assert!(!rule.out_of_reach(&[(800, 0.0), (900, 0.0), (1000, 0.0)], 1000));
        assert!(
            !ClimbRule { gain_db: -100.0 }
                .out_of_reach(&[(0, 0.0), (100, -0.2), (200, -0.3)], 1000)
        );
        assert!(rule.out_of_reach(&[(0, 0.0), (100, f64::NAN)], 1000));
    }

    #[test]
    fn the_rig_confirms_a_climb_only_by_the_margin_and_only_an_installable_rung() {
        let rule = ClimbRule { gain_db: 0.5 };
        assert!(rule.confirms((30.6, true), (30.0, true)));
        assert!(!rule.confirms((30.4, true), (30.0, true)));
        // Below the lower rung in closed loop, whatever the held-out pairs said.
        assert!(!rule.confirms((29.2, true), (30.0, true)));
        // A rung that would not install never wins; one that would beats one that would not.
        assert!(!rule.confirms((40.0, false), (30.0, true)));
        assert!(rule.confirms((30.1, true), (31.0, false)));
        assert!(!rule.confirms((f64::NAN, true), (30.0, true)));
    }

    #[test]
    fn only_a_negative_margin_comes_with_a_caveat() {
        assert_eq!(ClimbRule { gain_db: 0.0 }.caveat("--climb-gain"), None);
        assert_eq!(ClimbRule { gain_db: 0.5 }.caveat("--climb-gain"), None);
        let w = ClimbRule { gain_db: -2.0 }.caveat("climb_gain_db").unwrap();
        assert!(w.starts_with("climb_gain_db -2: "), "{w}");
        assert!(w.contains("up to 2 dB lower"), "{w}");
        assert!(
            ClimbRule { gain_db: -2.0 }
                .describe("x")
                .contains("negative margin")
        );
    }
}
