//! `ntrain = auto`: no more sampling pairs than the scene needs. The sampling images are captured
//! in rounds; after each round the `linear` rung is fitted on every sampling pair so far and
//! scored on the held-out test pairs in camera space (`model::forward_mse`: how
//! well its forward model predicts each capture). Another round is taken while the last one
//! lowered that held-out error enough ([`Rounds::next`]); the curve goes into the calibration
//! record (`model.json`, `calibration.sampling`).
//!
//! Why camera space, and why a mean squared error rather than decibels: on the virtual rig's
//! calibrations (docs/bench/calibrate.md, "Sampling rounds"), the held-out figure in decibels
//! gained alike on a white plane and on a dark texture (0.7–0.8 dB from 24 to 32 pairs) while
//! their closed loop did not (+0.01 against +0.28 dB): in decibels the gain is relative to the
//! model's own error, which is small beside what limits a white plane's closed loop. The error
//! removed is what adds to the closed loop's: 3 × 10⁻⁵ on the white plane, 4 × 10⁻⁴ on the dark
//! texture for those 8 pairs.
//!
//! The closed-loop pairs that follow are no more than the scene needs either: the first 8 are
//! judged ([`Rounds::loops`]) by how much of their closed-loop error (capture against desired
//! view) the model that compensated them leaves in its own prediction of the captures. Why
//! not by rounds scored on held-out pairs like the sampling pairs: on closed-loop pairs held
//! out, what a refit removed did not follow the closed loop (a white plane's first 8 more
//! pairs removed 1.3 × 10⁻⁵ for 0.005 dB in closed loop, a dark texture's third 8 removed
//! 1.4 × 10⁻⁵ for 0.16 dB): what a white plane's closed loop misses is light the projector
//! cannot give, which no refit changes. Such rounds also need 16 pairs before the first
//! judgement; the share tells the scenes apart from the first 8 (docs/bench/calibrate.md).

use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::record::RoundScore;

/// Sampling pairs of the first round.
pub const FIRST_ROUND: usize = 16;
/// Sampling pairs each later round adds.
pub const ROUND_STEP: usize = 8;
/// The most sampling pairs `auto` takes: as many as the fixed default (`fit::DEFAULT_TRAIN`,
/// checked where both are in reach). This file is a record type's home, which the model store
/// reads, so it imports nothing of the fit or the model.
pub const MOST_PAIRS: usize = 48;
/// The held-out camera-space mean squared error (encoded values in \[0, 1\], squared) a round of
/// [`ROUND_STEP`] pairs must remove for another to be taken: 10⁻⁴, the whole error of a 40 dB
/// image. Closed loop gained a quarter to a tenth of what the held-out error lost on the rig's
/// scenes, so a round that removes less gains at most about 0.05 dB on a surface with a closed
/// loop near 26 dB and 0.2 dB near 33 dB.
pub const DEFAULT_MARGIN_MSE: f64 = 1e-4;
/// Closed-loop pairs taken before `auto` judges whether more pay (when they follow the
/// sampling pairs): as many as a sampling round adds.
pub const LOOP_FIRST: usize = ROUND_STEP;
/// The share of the first closed-loop pairs' error (capture against desired view, in the
/// displayable area) that the compensating model's own error on them (its forward model's
/// prediction against the capture) must reach for more closed-loop pairs to be taken. On eleven
/// calibrations of ten scenes (docs/bench/calibrate.md, "Closed-loop pairs: as many as the
/// scene needs"), all the closed-loop pairs gained 0.01–0.03 dB in closed loop over the first
/// 8 where the share was 0.03–0.12 (a white plane, a textured plane, a curved wall twice),
/// 0.00–0.07 dB at 0.19–0.35, and 0.14–0.57 dB at 0.55–0.62 (camera noise with defocus, a
/// dark texture): more are taken from 0.15 on, so that stopping costs at most a few
/// hundredths of a decibel.
pub const DEFAULT_LOOP_SHARE: f64 = 0.15;

/// How many sampling images a calibration projects: a count, or `auto` ([`Rounds`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SamplingCount {
    Count(usize),
    Auto,
}

impl SamplingCount {
    /// The count, or the most `auto` may take.
    pub fn most(self) -> usize {
        match self {
            SamplingCount::Count(n) => n,
            SamplingCount::Auto => MOST_PAIRS,
        }
    }
}

impl std::fmt::Display for SamplingCount {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SamplingCount::Count(n) => write!(f, "{n}"),
            SamplingCount::Auto => f.write_str("auto"),
        }
    }
}

impl FromStr for SamplingCount {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        if s.trim().eq_ignore_ascii_case("auto") {
            return Ok(SamplingCount::Auto);
        }
        s.trim().parse::<usize>().map(SamplingCount::Count).map_err(|_| {
            format!("{s:?}: expected a number of sampling images, or \"auto\" (rounds until one no longer gains)")
        })
    }
}

/// A count as a number, `auto` as the string, as the configuration writes them.
impl Serialize for SamplingCount {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            SamplingCount::Count(n) => s.serialize_u64(*n as u64),
            SamplingCount::Auto => s.serialize_str("auto"),
        }
    }
}

impl<'de> Deserialize<'de> for SamplingCount {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl serde::de::Visitor<'_> for Visitor {
            type Value = SamplingCount;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("a number of sampling images, or \"auto\"")
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<SamplingCount, E> {
                usize::try_from(v)
                    .map(SamplingCount::Count)
                    .map_err(|_| E::custom(format!("{v}: too many sampling images")))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<SamplingCount, E> {
                usize::try_from(v)
                    .map(SamplingCount::Count)
                    .map_err(|_| E::custom(format!("{v}: expected a count of 0 or more")))
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<SamplingCount, E> {
                v.parse().map_err(E::custom)
            }
        }
        d.deserialize_any(Visitor)
    }
}

/// The rounds of `ntrain = auto`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rounds {
    /// Sampling pairs of the first round.
    pub first: usize,
    /// Pairs each later round adds.
    pub step: usize,
    /// The most sampling pairs.
    pub most: usize,
    /// The held-out camera-space mean squared error a round of `step` pairs must remove.
    pub margin_mse: f64,
    /// The closed-loop pairs follow the sampling pairs chosen (as many, or only the first
    /// `loop_first` when those show that more would not pay, [`Rounds::loops`]), rather than a
    /// count asked for.
    pub loops_follow: bool,
    /// Closed-loop pairs judged before more are taken.
    pub loop_first: usize,
    /// The share of the closed-loop error the model's own error must reach for more.
    pub loop_share: f64,
}

/// The first closed-loop pairs' figures that [`Rounds::loops`] judges by, in the displayable
/// area, camera values (encoded, in \[0, 1\]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopScore {
    /// Closed-loop pairs scored.
    pub pairs: usize,
    /// The compensating model's forward prediction of each capture against the capture: mean
    /// squared error.
    pub model_mse: f64,
    /// Each capture against its desired view: mean squared error.
    pub closed_loop_mse: f64,
}

impl Rounds {
    /// The default rounds, up to `most` sampling pairs.
    pub fn new(most: usize, loops_follow: bool) -> Self {
        Rounds {
            first: FIRST_ROUND.min(most),
            step: ROUND_STEP,
            most,
            margin_mse: DEFAULT_MARGIN_MSE,
            loops_follow,
            loop_first: LOOP_FIRST,
            loop_share: DEFAULT_LOOP_SHARE,
        }
    }

    /// How many closed-loop pairs to take in all, of `follow` (as many as the sampling pairs),
    /// after the first ones scored `score`, and why. A closed loop's error is the model's,
    /// propagated through the compensation, plus what no model removes (light the projector
    /// cannot give, camera noise); closed-loop pairs refit the model where the compensation
    /// drives the projector, so they pay only where the model's own error there is a good part
    /// of the closed loop's. A figure that is not a number takes them all.
    pub fn loops(&self, score: &LoopScore, follow: usize) -> (usize, String) {
        let share = score.model_mse / score.closed_loop_mse;
        let figures = format!(
            "on the first {} the model's own camera-space error ({:.1e}) is {:.1} % of the \
             closed loop's ({:.1e})",
            score.pairs,
            score.model_mse,
            100.0 * share,
            score.closed_loop_mse
        );
        let limit = 100.0 * self.loop_share;
        if follow <= score.pairs {
            (follow, format!("{figures}; all {follow} taken"))
        } else if share < self.loop_share {
            (
                score.pairs,
                format!(
                    "{figures}, less than the {limit:.0} % at which more pay: what the closed \
                     loop misses is beyond the model (light the projector cannot give, camera \
                     noise)"
                ),
            )
        } else {
            (
                follow,
                format!(
                    "{figures}, not less than the {limit:.0} % at which more pay: the model \
                     limits the closed loop there, so as many as the sampling pairs"
                ),
            )
        }
    }

    /// [`Rounds::loops`]'s rule in words, for the record.
    pub fn describe_loops(&self) -> String {
        format!(
            "closed-loop pairs: {} first; then as many as the sampling pairs when the \
             compensating linear rung's camera-space error on them is at least {:.0} % of \
             their closed-loop error (both in the displayable area)",
            self.loop_first,
            100.0 * self.loop_share
        )
    }

    /// After the rounds scored so far (in order), the sampling pairs of the next round, or why
    /// none is taken. A round's gain is the held-out error it removed, scaled to `step` pairs.
    pub fn next(&self, curve: &[RoundScore]) -> Result<usize, String> {
        let Some(last) = curve.last() else {
            return Ok(self.first);
        };
        if last.pairs >= self.most {
            return Err(format!(
                "{} sampling pairs, the most `auto` takes",
                last.pairs
            ));
        }
        if let [.., before, last] = curve {
            let removed = (before.mse - last.mse) * self.step as f64
                / (last.pairs.saturating_sub(before.pairs)).max(1) as f64;
            if removed < self.margin_mse {
                return Err(format!(
                    "from {} to {} pairs the held-out camera-space error fell by {:.1e} per \
                     {} pairs, less than the {:.1e} another round must remove",
                    before.pairs, last.pairs, removed, self.step, self.margin_mse
                ));
            }
        }
        Ok((last.pairs + self.step).min(self.most))
    }

    /// The next round's sampling pairs when the round of `pairs` being scored cannot end the
    /// rounds, whatever its score: it is the first (a gain needs two scores) and not already
    /// the most. `None` when its score decides ([`Rounds::next`]).
    pub fn next_regardless(&self, curve: &[RoundScore], pairs: usize) -> Option<usize> {
        (curve.is_empty() && pairs < self.most).then(|| (pairs + self.step).min(self.most))
    }

    /// The rule in words, for the record.
    pub fn describe(&self) -> String {
        format!(
            "sampling pairs in rounds: {} first, then {} more while the last round lowered the \
             linear rung's held-out camera-space mean squared error (the test pairs) by at \
             least {:.1e} per {} pairs, up to {}",
            self.first, self.step, self.margin_mse, self.step, self.most
        )
    }
}

/// The rounds a calibration with `count` sampling images takes: `None` for a count; for
/// `auto`, the default rounds, whose closed-loop pairs follow the sampling pairs chosen unless
/// a count of them was asked for (`loops_asked`).
pub fn rounds_for(count: SamplingCount, loops_asked: Option<usize>) -> Option<Rounds> {
    match count {
        SamplingCount::Count(_) => None,
        SamplingCount::Auto => Some(Rounds::new(MOST_PAIRS, loops_asked.is_none())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn round(pairs: usize, mse: f64) -> RoundScore {
        RoundScore {
            pairs,
            mse,
            psnr: crate::metrics::psnr_from_mse(mse),
            seconds: 1.0,
        }
    }

    #[test]
    fn rounds_go_on_while_a_round_removes_the_margin() {
        let r = Rounds::new(48, true);
        assert_eq!(r.next(&[]), Ok(16));
        // One score: nothing to compare yet.
        assert_eq!(r.next(&[round(16, 3e-3)]), Ok(24));
        // Dark texture (measured): 2.9e-3 → 2.2e-3 removes 7e-4.
        assert_eq!(r.next(&[round(16, 2.9e-3), round(24, 2.2e-3)]), Ok(32));
        // White plane (measured): 2.45e-4 → 1.76e-4 removes 7e-5.
        let why = r
            .next(&[round(16, 2.45e-4), round(24, 1.76e-4)])
            .unwrap_err();
        assert!(why.contains("from 16 to 24 pairs"), "{why}");
        // The margin is per `step` pairs: 16 pairs that remove 1.5e-4 remove 7.5e-5 per 8.
        assert!(r.next(&[round(24, 5e-4), round(40, 3.5e-4)]).is_err());
        // Never past the most, and the last round is cut to it.
        assert_eq!(r.next(&[round(32, 9e-3), round(40, 5e-3)]), Ok(48));
        assert!(r.next(&[round(40, 9e-3), round(48, 5e-3)]).is_err());
        // A fit that got worse stops the rounds.
        assert!(r.next(&[round(16, 1e-3), round(24, 2e-3)]).is_err());
        // Fewer most pairs than a first round: one round of them.
        let small = Rounds::new(10, true);
        assert_eq!(small.next(&[]), Ok(10));
        assert!(small.next(&[round(10, 1e-2)]).is_err());
    }

    fn loop_score(model_mse: f64, closed_loop_mse: f64) -> LoopScore {
        LoopScore {
            pairs: 8,
            model_mse,
            closed_loop_mse,
        }
    }

    /// The figures measured on the rig's scenes (docs/bench/calibrate.md): a white plane and a
    /// curved wall stop at the first 8, a dark texture and a depth step take them all.
    #[test]
    fn closed_loop_pairs_go_on_where_the_model_limits_the_closed_loop() {
        let r = Rounds::new(48, true);
        for (model, closed) in [(8.42e-5, 3.40e-3), (7.46e-5, 6.01e-4)] {
            let (n, why) = r.loops(&loop_score(model, closed), 24);
            assert_eq!(n, 8, "{why}");
            assert!(why.contains("less than the 15 %"), "{why}");
        }
        for (model, closed) in [(2.19e-4, 3.56e-4), (2.70e-4, 1.21e-3)] {
            let (n, why) = r.loops(&loop_score(model, closed), 48);
            assert_eq!(n, 48, "{why}");
            assert!(why.contains("not less than the 15 %"), "{why}");
        }
        // Not a number (or no closed-loop error to compare with): all of them; as many as the
        // first: nothing to judge.
        assert_eq!(r.loops(&loop_score(f64::NAN, 1e-3), 24).0, 24);
        assert_eq!(r.loops(&loop_score(1e-4, 0.0), 24).0, 24);
        let (n, why) = r.loops(&loop_score(1e-3, 1e-3), 8);
        assert!(n == 8 && why.contains("all 8 taken"), "{why}");
        assert!(r.describe_loops().contains("8 first"));
    }

    /// What the first round's fit may run behind is what any score of it leads to.
    #[test]
    fn the_round_after_the_first_does_not_depend_on_its_score() {
        for (most, pairs) in [(48, 16), (20, 16), (16, 16), (10, 10)] {
            let r = Rounds::new(most, true);
            for mse in [1e-1, 1e-6, f64::NAN] {
                let after = r.next(&[round(pairs, mse)]).ok();
                assert_eq!(r.next_regardless(&[], pairs), after, "{most} {pairs} {mse}");
            }
            // Once a round is scored, the next one depends on the score.
            assert_eq!(r.next_regardless(&[round(pairs, 1e-3)], pairs + 8), None);
        }
    }

    #[test]
    fn a_count_or_auto_is_read_and_anything_else_named() {
        assert_eq!("auto".parse(), Ok(SamplingCount::Auto));
        assert_eq!("AUTO".parse(), Ok(SamplingCount::Auto));
        assert_eq!("24".parse(), Ok(SamplingCount::Count(24)));
        let e = "many".parse::<SamplingCount>().unwrap_err();
        assert!(e.contains("\"many\"") && e.contains("\"auto\""), "{e}");
        #[derive(Deserialize)]
        struct T {
            n: SamplingCount,
        }
        let t: T = toml::from_str("n = 12").unwrap();
        assert_eq!(t.n, SamplingCount::Count(12));
        let t: T = toml::from_str("n = \"auto\"").unwrap();
        assert_eq!(t.n, SamplingCount::Auto);
        assert!(toml::from_str::<T>("n = -3").is_err());
        assert!(toml::from_str::<T>("n = 1.5").is_err());
        assert_eq!(SamplingCount::Auto.to_string(), "auto");
        assert_eq!(SamplingCount::Auto.most(), 48);
    }
}
