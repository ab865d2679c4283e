//! `--method auto`: the ladder climbed only as far as the scene needs (docs/architecture.md,
//! "Models").
//!
//! 1. The linear rungs (`linear`, and `linear-sl` when the setup has structured light) are
//!    fitted on the sampling pairs but the last sixth (at least 4) and scored on those with the
//!    paper protocol; the best is the rung to beat. Closed-loop pairs at the end of the data
//!    (`calibrate` takes them after the sampling pairs) are not sampling pairs. A lone `linear`
//!    is scored there only when the climb is judged there too.
//! 2. The CompenNet++ rung the machine can afford ([`climb_rung`]: `compennet++-res`, `linear`
//!    plus a CPU-sized correction, on the CPU; `compennet++-res-full`, the same with a
//!    full-size correction, on a GPU) is trained. When the caller projects the result
//!    (`calibrate`, [`Request::rig_judges`]), the rig judges: the rung is trained once on every
//!    pair of its kind (as in step 3) and the best linear rung fitted beside it, both projected
//!    on the verification images, and the climbed rung is kept only if it beats the linear one
//!    there by the margin ([`settle_climb`], default [`DEFAULT_RIG_GAIN_DB`]). No held-out
//!    figure is asked: on dark textures the held-out closed-loop figure showed +0.1 dB where
//!    the rig showed +0.23 to +0.32, and overstated it elsewhere (docs/bench/ladder.md, "The
//!    rig judges the climb"). Offline (`train`), with no rig, it is judged:
//!    - on a setup with enough closed-loop pairs ([`judges_on_loop_pairs`]):
//!      trained on every pair but the last sixth of the closed-loop ones (at least 4), and
//!      judged on those: how much closer than `linear`'s its compensations of their desired
//!      views come to the projector images that move their captures towards the views
//!      ([`LoopHeldOut`]). That is what its correction learns and what closed loop asks; on
//!      sampling captures a network gains from averaging capture noise away, which closed loop
//!      does not repay. In projector pixels the figure overstates the camera's gain where the
//!      surface is dark, so the rig's check stays (docs/bench/ladder.md). It is scored there
//!      as it trains, and its training stops early once its gain has slowed out of reach of
//!      the margin ([`ClimbRule::out_of_reach`]);
//!    - otherwise trained on the sampling pairs the linear rungs were fitted on and judged on
//!      the held-out ones, scored as they were, as it trains, and stopped early as above.
//!
//!    Either way its training also stops once its gain has settled past the margin
//!    ([`ClimbRule::settled`]). It climbs only if it beats the rung below by the climbing
//!    rule's margin ([`ClimbRule`]); the service's progressive calibration, which projects,
//!    lets the rig judge as `calibrate` does.
//! 3. A climbed rung is trained again from its start on every pair of the kind it was judged on
//!    ([`retrain`]): the model judged saw fewer (kept to the end on 45 of 54 pairs, as it was
//!    before, it scored 0.18–0.31 dB below on a recorded fabric). Otherwise the best
//!    linear rung is fitted again on every pair, closed-loop ones included (`linear` takes the
//!    geometry the earlier fits of this `auto` fitted on the same first pairs,
//!    [`crate::linear::GeometryMemo`]).
//!
//! The rule, every candidate's held-out figures and the time each took go into `model.json`
//! (`training.auto`).

use std::time::Instant;

use super::rule::{ClimbRule, DEFAULT_CLIMB_GAIN_DB, DEFAULT_RIG_GAIN_DB};
use super::{MIN_TRAIN, Request, Summary, TrainDevice, TrainingData, compennet, linear_rungs};
use crate::dataset::{Reference, Setup};
use crate::error::Result;
use crate::model::{Method, MethodChoice, Model};
use crate::record::{AutoCandidate, AutoEvidence, ClosedLoopScore, LoopHeldOut, Retrained};

/// The CompenNet++ rung a training device can afford: the residual rung, `linear` plus a
/// CompenNet correction that starts at zero, so that it starts where `linear` ends. On the CPU
/// the correction is CPU-sized (`compennet++-res`); on a GPU it is full-size
/// (`compennet++-res-full`: the paper's widths on the whole network side). The paper's
/// `compennet++`, which learns the whole image from its pre-trained start, is not a rung `auto`
/// climbs to: on the virtual rig it scored below `linear` in every run (docs/bench/gpu-h100.md).
pub fn climb_rung(device: TrainDevice) -> Method {
    match device {
        TrainDevice::Cpu => Method::CompenNetPpRes,
        TrainDevice::Cuda(_) => Method::CompenNetPpResFull,
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
    data: TrainingData<'_>,
    start: Instant,
    mut progress: impl FnMut(&str, usize, usize),
) -> Result<(Model, Summary)> {
    let rule = ClimbRule {
        gain_db: req.climb_gain_db.unwrap_or(if req.rig_judges {
            DEFAULT_RIG_GAIN_DB
        } else {
            DEFAULT_CLIMB_GAIN_DB
        }),
    };
    // Its `linear` fits (the rungs scored, the residual rung's linear part, the last refit)
    // see the same sampling pairs first, so they share one geometry fit.
    let shared;
    let req = match req.geometry_memo {
        Some(_) => req,
        None => {
            shared = Request {
                geometry_memo: Some(Default::default()),
                ..req.clone()
            };
            &shared
        }
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
    let gray = setup.reference_path(Reference::Gray);
    // Why the climb is not judged now, if it is not.
    let no_climb = if req.climb_later {
        Some(format!(
            "{rung} is judged later, on the closed-loop pairs taken with the linear rung"
        ))
    } else if !gray.is_file() {
        Some(format!(
            "no gray surface capture ({}): {rung} cannot be trained",
            gray.display()
        ))
    } else if variant.is_none() {
        Some(format!("{rung} is not a CompenNet++ rung `auto` can train"))
    } else {
        None
    };
    // The linear rungs are scored on held-out sampling pairs when there are two to choose
    // from, or when the climb is judged there against the best of them. A lone `linear` judged
    // against nothing there is not fitted for it (a fit of its own, 15–20 s at 800×600).
    let rungs = linear_rungs::linear_rungs(setup).len();
    let compares = |no_climb: &Option<String>| {
        rungs > 1 || (no_climb.is_none() && !on_loop_pairs && !req.rig_judges)
    };
    let held = held_out(sampling);
    if compares(&no_climb) && sampling < held + MIN_TRAIN {
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
            judged: None,
            retrained: None,
            live: None,
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
    // The climb's live pass, timed where the model is to play, when the caller asked: a rung
    // the display cannot keep up with is not trained. A pass that cannot be sized is the
    // caller's error; one that cannot be timed (or built on that GPU) is a climb not taken.
    let live = match (&no_climb, &req.live) {
        (None, Some(probe)) => Some(probe.cost(&pass_shape(setup, req, rung, &data)?)),
        _ => None,
    };
    let (no_climb, live) = match live {
        Some(Ok(cost)) if !cost.fits() => (
            Some(format!(
                "{}: the climb is not trained, the best linear rung is kept",
                cost.describe()
            )),
            Some(cost),
        ),
        Some(Ok(cost)) => (no_climb, Some(cost)),
        Some(Err(e)) => (
            Some(format!(
                "{rung}'s live pass could not be timed on the GPU that is to play it ({e}): \
                 the climb is not trained, the best linear rung is kept"
            )),
            None,
        ),
        None => (no_climb, None),
    };
    if let Some(cost) = &live {
        tracing::info!("auto: {}", cost.describe());
    }
    let compare = compares(&no_climb);
    let cut = sampling.saturating_sub(held);
    let (fit_pairs, held_pairs) = (
        (&data.captures[..cut], &data.targets[..cut]),
        (&data.captures[cut..sampling], &data.targets[cut..sampling]),
    );
    let mut candidates = if compare {
        linear_rungs::score_linear_rungs(
            setup,
            req,
            fit_pairs,
            held_pairs,
            data.theta,
            &mut progress,
        )?
    } else {
        Vec::new()
    };
    let best_linear = candidates
        .iter()
        .max_by(|a, b| a.held_out_psnr.total_cmp(&b.held_out_psnr))
        .map_or((Method::Linear, f64::NAN), |c| (c.method, c.held_out_psnr));

    let mut why: Vec<String> = no_climb.iter().cloned().collect();
    if !compare {
        why.push(
            "`linear` is the only linear rung (no structured-light captures): not scored on \
             held-out sampling pairs"
                .into(),
        );
    }
    let mut climbed = None;
    let mut loop_held_out = None;
    let mut judged_on_sampling = None;
    let mut retrained = None;
    if let (None, Some(variant)) = (&no_climb, variant) {
        // The rig judges (`req.rig_judges`): no held-out judgement, the rung trained on every
        // pair of its kind, as it trains alone, for the caller to project beside the best
        // linear rung. Otherwise it is judged on held-out pairs first.
        let climbs = req.rig_judges || {
            let (upper, lower) = if on_loop_pairs {
                let judged = train_judged(
                    setup,
                    req,
                    (rung, variant),
                    &data,
                    loops,
                    rule,
                    &mut progress,
                )?;
                let (up, lin) = judged.figures();
                loop_held_out = Some(judged);
                (up, lin)
            } else {
                // The rung trains on the sampling pairs the linear rungs were fitted on (its
                // linear part on the request's lattice, as theirs) and is judged on the
                // held-out ones against the best of them.
                let t0 = Instant::now();
                let sub_req = Request {
                    method: MethodChoice::Rung(rung),
                    ntrain: Some(cut),
                    ..req.clone()
                };
                let judge = compennet::Judge {
                    indices: (cut + 1..=sampling).collect(),
                    closed_loop: false,
                    lower_psnr: Some(best_linear.1),
                    captures: &data.captures,
                    targets: &data.targets,
                    rule,
                };
                let (_, _, judged) = compennet::train_compennet(
                    setup,
                    &sub_req,
                    (rung, variant),
                    data.first(cut),
                    Some(judge),
                    t0,
                    &mut progress,
                )?;
                let judged = judged.ok_or_else(|| {
                    crate::error::Error::Failed(format!(
                        "{rung}: its training returned no judgement"
                    ))
                })?;
                let up = judged.scores.get(1).ok_or_else(|| {
                    crate::error::Error::Failed(format!("{rung}: its judgement has no score"))
                })?;
                candidates.push(AutoCandidate {
                    fit_seconds: t0.elapsed().as_secs_f64(),
                    ..up.clone()
                });
                tracing::info!(
                    "auto: {rung} {:.2} dB against {} {:.2} dB on {held} held-out pairs (climbs \
                     at {:+} dB){}",
                    up.held_out_psnr,
                    best_linear.0,
                    best_linear.1,
                    rule.gain_db,
                    judged.training.stop()
                );
                let up = up.held_out_psnr;
                judged_on_sampling = Some(judged.training);
                (up, best_linear.1)
            };
            rule.climbs(upper, lower)
        };
        if climbs {
            // On the pairs of its kind: judged on sampling pairs (paper protocol), it trains
            // again on those, not on a few closed-loop pairs after them, which would make its
            // correction another one (on closed-loop pairs) than the one judged.
            let pairs = if on_loop_pairs { n } else { sampling };
            if req.rig_judges {
                tracing::info!(
                    "auto: training {rung} on all {pairs} pairs for the rig to judge beside \
                     the best linear rung"
                );
            } else {
                tracing::info!(
                    "auto: {rung} climbs; training it again from its start on all {pairs} pairs"
                );
            }
            let (model, summary, record) = retrain(
                setup,
                req,
                (rung, variant),
                &data.first(pairs),
                &mut progress,
            )?;
            retrained = Some(record);
            climbed = Some((model, summary));
        }
    }
    let chosen = climbed
        .as_ref()
        .map_or(best_linear.0, |(m, _)| m.meta.method);
    let evidence = AutoEvidence {
        rule: if req.rig_judges && no_climb.is_none() {
            rule.describe_rig_judged(rung)
        } else if loop_held_out.is_some() {
            rule.describe_on_loop_pairs(rung)
        } else {
            rule.describe("held-out training pairs")
        },
        chosen,
        why: (!why.is_empty()).then(|| why.join("; ")),
        held_out: compare.then_some(held),
        fitted_on: compare.then_some(cut),
        required_gain_db: Some(rule.gain_db),
        candidates,
        closed_loop: Vec::new(),
        loop_held_out,
        judged: judged_on_sampling,
        retrained,
        live,
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

/// The shapes this training would give `rung`'s live pass: the captures' camera size, `req`'s
/// lattice (resolved), the data root's network size and the projector's resolution (an input
/// error when the setup does not record it).
fn pass_shape(
    setup: &Setup,
    req: &Request,
    rung: Method,
    data: &TrainingData<'_>,
) -> Result<super::PassShape> {
    let network = setup.root().network_size()?;
    let projector = super::projector_size(setup, req)?.0.ok_or_else(|| {
        crate::Error::Input(format!(
            "{}: the projector's resolution is not known (no structured-light patterns in its \
             data root, no calibration manifest), so the climb's live pass cannot be sized for \
             it; leave the refresh rate out, or train on a setup that records it",
            setup.path().display()
        ))
    })?;
    let lattice = req
        .lattice
        .unwrap_or_else(|| super::default_lattice(network, Some(projector)));
    let camera = data
        .captures
        .first()
        .map(|c| c.size())
        .ok_or_else(|| crate::Error::Input("no training pairs to size the live pass".into()))?;
    Ok(super::PassShape {
        method: rung,
        camera,
        lattice,
        network,
        projector,
    })
}

/// A residual rung (`rung`, of `variant`) trained on every pair of `data` but the last sixth of its
/// `loops` trailing closed-loop pairs, and judged on those as it trains ([`compennet::Judge`]):
/// its training stops early when it cannot reach `rule`'s margin or has settled past it. `req`
/// has its lattice resolved. Returns the judgement; the model it trained saw only some of the
/// pairs, so it is not kept ([`retrain`]).
fn train_judged(
    setup: &Setup,
    req: &Request,
    (rung, variant): (Method, crate::nn::compennetpp::Variant),
    data: &TrainingData<'_>,
    loops: usize,
    rule: ClimbRule,
    progress: impl FnMut(&str, usize, usize),
) -> Result<LoopHeldOut> {
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
        closed_loop: true,
        lower_psnr: None,
        captures: &data.captures,
        targets: &data.targets,
        rule,
    };
    let (_, _, judged) = compennet::train_compennet(
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
        judged.training.stop()
    );
    Ok(judged)
}

/// The climbed rung (`rung`, of `variant`) trained from its start on every pair of `data`, with
/// `req`'s settings and seed: the model `auto` keeps. With `req.rig_judges` it is the only
/// training, for the rig to judge; otherwise it is trained again because the judged one saw
/// only some of the pairs. On a recorded fabric, the model kept before this (trained to its end on 45
/// of the 54 pairs) scored 0.18–0.31 dB below the rung trained on all 54 (docs/bench/ladder.md).
/// Returns the model, its summary and the record.
fn retrain(
    setup: &Setup,
    req: &Request,
    (rung, variant): (Method, crate::nn::compennetpp::Variant),
    data: &TrainingData<'_>,
    progress: impl FnMut(&str, usize, usize),
) -> Result<(Model, Summary, Retrained)> {
    let t = Instant::now();
    let n = data.captures.len();
    let every = Request {
        method: MethodChoice::Rung(rung),
        ntrain: Some(n),
        ..req.clone()
    };
    let (model, summary, _) = compennet::train_compennet(
        setup,
        &every,
        (rung, variant),
        data.first(n),
        None,
        t,
        progress,
    )?;
    let record = Retrained {
        method: rung,
        pairs: n,
        seconds: t.elapsed().as_secs_f64(),
        after_judgement: !req.rig_judges,
    };
    Ok((model, summary, record))
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
    // No candidates: `linear` was the only linear rung, not scored on sampling pairs.
    let lower = evidence.best_linear().map_or(Method::Linear, |c| c.method);
    tracing::info!(
        "auto: fitting {lower} for the rig to compare with {} in closed loop",
        climbed.meta.method
    );
    let req = Request {
        method: MethodChoice::Rung(lower),
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

/// `auto`'s evidence for a person: each candidate's held-out figures and time, the choice and
/// the rule, one line each.
pub fn evidence_lines(evidence: &AutoEvidence) -> Vec<String> {
    let mut out = Vec::new();
    if let (Some(held), Some(fitted)) = (evidence.held_out, evidence.fitted_on) {
        let figures: Vec<String> = evidence
            .candidates
            .iter()
            .map(|c| {
                format!(
                    "{} {:.2} dB / SSIM {:.3} ({:.1} s)",
                    c.method, c.held_out_psnr, c.held_out_ssim, c.fit_seconds
                )
            })
            .collect();
        out.push(format!(
            "auto: on {held} held-out {}pairs (fitted on {fitted}): {}",
            if evidence.loop_held_out.is_some() {
                "sampling "
            } else {
                ""
            },
            figures.join(", ")
        ));
    }
    if let Some(j) = &evidence.judged {
        let curve: Vec<String> = j.curve.iter().map(|c| format!("{:.2}", c.psnr)).collect();
        out.push(format!(
            "auto: the climb rung on the held-out pairs as it trained: {} dB{}",
            curve.join(", "),
            j.stop()
        ));
    }
    if let Some(why) = &evidence.why {
        out.push(format!("auto: {why}"));
    }
    // A pass over its budget is in `why`.
    if let Some(live) = evidence.live.as_ref().filter(|l| l.fits()) {
        out.push(format!("auto: {}", live.describe()));
    }
    if let Some(l) = &evidence.loop_held_out {
        let figures: Vec<String> = l
            .scores
            .iter()
            .map(|c| {
                format!(
                    "{} {:.2} dB / SSIM {:.3}{}",
                    c.method,
                    c.held_out_psnr,
                    c.held_out_ssim,
                    if c.fit_seconds > 0.0 {
                        format!(" ({:.1} s)", c.fit_seconds)
                    } else {
                        String::new()
                    }
                )
            })
            .collect();
        out.push(format!(
            "auto: on {} held-out closed-loop pairs (the correction trained on {}), against \
                 the projector images that move their captures towards the desired views: {}{}",
            l.pairs,
            l.trained_on,
            figures.join(", "),
            l.training.stop()
        ));
    }
    if !evidence.closed_loop.is_empty() {
        let figures: Vec<String> = evidence
            .closed_loop
            .iter()
            .map(|c| {
                format!(
                    "{} {:.2} dB / SSIM {:.3}{}",
                    c.method,
                    c.psnr,
                    c.ssim,
                    if c.passed { "" } else { " (not installable)" }
                )
            })
            .collect();
        out.push(format!(
            "auto: closed loop on the rig: {}",
            figures.join(", ")
        ));
    }
    out.push(format!(
        "auto: chose {} by the rule: {}",
        evidence.chosen, evidence.rule
    ));
    if let Some(r) = &evidence.retrained {
        let kept = if evidence.chosen == r.method {
            String::new()
        } else {
            format!("; the rig then kept {}", evidence.chosen)
        };
        out.push(if r.after_judgement {
            format!(
                "auto: having climbed, {} trained again from its start on {} pairs, the \
                     held-out ones included ({:.1} s){kept}",
                r.method, r.pairs, r.seconds
            )
        } else {
            format!(
                "auto: {} trained on all {} pairs for the rig to judge ({:.1} s){kept}",
                r.method, r.pairs, r.seconds
            )
        });
    }
    if !evidence.chosen.is_linear()
        && evidence.closed_loop.is_empty()
        && evidence.loop_held_out.is_none()
    {
        out.push(
            "auto: this climb rests on held-out captures alone, where capture noise favours \
                 a network; `compend calibrate --method auto` also checks it on the rig, in \
                 closed loop"
                .into(),
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_climb_rung_and_the_held_out_pairs_follow_the_machine_and_the_data() {
        assert_eq!(climb_rung(TrainDevice::Cpu), Method::CompenNetPpRes);
        assert_eq!(climb_rung(TrainDevice::Cuda(0)), Method::CompenNetPpResFull);
        assert_eq!(held_out(48), 8);
        assert_eq!(held_out(12), 4);
        // Closed-loop pairs judge a climb when 4 can be held out and 4 trained on.
        assert!(!judges_on_loop_pairs(0));
        assert!(!judges_on_loop_pairs(7));
        assert!(judges_on_loop_pairs(8));
        assert!(judges_on_loop_pairs(48));
    }
}
