//! The rungs of the model ladder by name (docs/architecture.md, "Models"): what `train
//! --method` accepts, what `model.json` records, what `bench` reports.

use serde::{Deserialize, Serialize};

/// A model rung. The names (`linear`, `compennet++-cpu`, …) are what the command line takes and
/// what `model.json`'s `method` holds.
#[derive(
    Clone,
    Copy,
    Debug,
    PartialEq,
    Eq,
    Hash,
    PartialOrd,
    Ord,
    Serialize,
    Deserialize,
    clap::ValueEnum,
)]
pub enum Method {
    /// Learned affine + TPS geometry, per-pixel linear colour model in linear light.
    #[serde(rename = "linear")]
    #[value(name = "linear")]
    Linear,
    /// Geometry from the structured-light captures (cam/raw/sl), the same colour model.
    #[serde(rename = "linear-sl")]
    #[value(name = "linear-sl")]
    LinearSl,
    /// CompenNet++, the paper's fastest schedule: 48 pairs, batch 16, 500 iterations.
    #[serde(rename = "compennet++-faster")]
    #[value(name = "compennet++-faster")]
    CompenNetPpFaster,
    /// CompenNet++, the paper's "fast" schedule.
    #[serde(rename = "compennet++-fast")]
    #[value(name = "compennet++-fast")]
    CompenNetPpFast,
    /// CompenNet++ without the geometry refinement CNN.
    #[serde(rename = "compennet++-norefine")]
    #[value(name = "compennet++-norefine")]
    CompenNetPpNoRefine,
    /// The full CompenNet++: 500 pairs, batch 48, 1 500 iterations.
    #[serde(rename = "compennet++")]
    #[value(name = "compennet++")]
    CompenNetPp,
    /// CompenNet on a fixed grid from the decoded structured light (two-step baseline).
    #[serde(rename = "compennet-sl")]
    #[value(name = "compennet-sl")]
    CompenNetSl,
    /// The CPU-sized rung: half the network side, half the channel widths.
    #[serde(rename = "compennet++-cpu")]
    #[value(name = "compennet++-cpu")]
    CompenNetPpCpu,
    /// `linear` plus a correction learned by the CPU-sized CompenNet on `linear`'s geometry,
    /// starting at zero: it starts where `linear` ends.
    #[serde(rename = "compennet++-res")]
    #[value(name = "compennet++-res")]
    CompenNetPpRes,
    /// `linear` plus a correction learned by the full-size CompenNet (the paper's widths, the
    /// whole network side) on `linear`'s geometry, starting at zero: the residual rung for a GPU.
    #[serde(rename = "compennet++-res-full")]
    #[value(name = "compennet++-res-full")]
    CompenNetPpResFull,
}

impl Method {
    /// Every rung, cheapest family first.
    pub const ALL: [Method; 10] = [
        Method::Linear,
        Method::LinearSl,
        Method::CompenNetPpFaster,
        Method::CompenNetPpFast,
        Method::CompenNetPpNoRefine,
        Method::CompenNetPp,
        Method::CompenNetSl,
        Method::CompenNetPpCpu,
        Method::CompenNetPpRes,
        Method::CompenNetPpResFull,
    ];

    /// The name on the command line and in `model.json`.
    pub fn name(self) -> &'static str {
        match self {
            Method::Linear => "linear",
            Method::LinearSl => "linear-sl",
            Method::CompenNetPpFaster => "compennet++-faster",
            Method::CompenNetPpFast => "compennet++-fast",
            Method::CompenNetPpNoRefine => "compennet++-norefine",
            Method::CompenNetPp => "compennet++",
            Method::CompenNetSl => "compennet-sl",
            Method::CompenNetPpCpu => "compennet++-cpu",
            Method::CompenNetPpRes => "compennet++-res",
            Method::CompenNetPpResFull => "compennet++-res-full",
        }
    }

    /// The rung of a name; `None` for anything else.
    pub fn from_name(name: &str) -> Option<Method> {
        Method::ALL.into_iter().find(|m| m.name() == name)
    }

    /// The `linear` family: closed-form CPU fits with an output lattice.
    pub fn is_linear(self) -> bool {
        matches!(self, Method::Linear | Method::LinearSl)
    }

    /// A residual rung: `linear` plus a CompenNet correction that starts at zero
    /// (`compennet++-res`, `compennet++-res-full`).
    pub fn is_residual(self) -> bool {
        crate::nn::compennetpp::Variant::from_method(self.name()).is_some_and(|v| v.residual())
    }

    /// Every name, comma-separated, for error messages.
    pub fn names() -> String {
        Method::ALL.map(Method::name).join(", ")
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Method {
    type Err = crate::Error;
    fn from_str(s: &str) -> crate::Result<Self> {
        Method::from_name(s).ok_or_else(|| {
            crate::Error::Input(format!(
                "method `{s}`: not available; methods: {}",
                Method::names()
            ))
        })
    }
}

/// What `train --method` (and `bench --methods`) accept: a rung, or `auto`, which climbs the
/// ladder only as far as held-out pairs show a gain (the rule is in [`crate::fit::ClimbRule`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MethodChoice {
    Auto,
    Rung(Method),
}

impl MethodChoice {
    const ALL: [MethodChoice; 11] = [
        MethodChoice::Auto,
        MethodChoice::Rung(Method::Linear),
        MethodChoice::Rung(Method::LinearSl),
        MethodChoice::Rung(Method::CompenNetPpFaster),
        MethodChoice::Rung(Method::CompenNetPpFast),
        MethodChoice::Rung(Method::CompenNetPpNoRefine),
        MethodChoice::Rung(Method::CompenNetPp),
        MethodChoice::Rung(Method::CompenNetSl),
        MethodChoice::Rung(Method::CompenNetPpCpu),
        MethodChoice::Rung(Method::CompenNetPpRes),
        MethodChoice::Rung(Method::CompenNetPpResFull),
    ];

    /// Whether it may train a CompenNet++ network (on `--device`): a CompenNet++ rung, or
    /// `auto`, which may climb to one.
    pub fn may_train_a_network(self) -> bool {
        match self {
            MethodChoice::Auto => true,
            MethodChoice::Rung(m) => !m.is_linear(),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            MethodChoice::Auto => "auto",
            MethodChoice::Rung(m) => m.name(),
        }
    }
}

impl std::fmt::Display for MethodChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for MethodChoice {
    type Err = crate::Error;
    fn from_str(s: &str) -> crate::Result<Self> {
        if s == "auto" {
            return Ok(MethodChoice::Auto);
        }
        Method::from_str(s).map(MethodChoice::Rung).map_err(|_| {
            crate::Error::Input(format!(
                "method `{s}`: not available; methods: {}, auto",
                Method::names()
            ))
        })
    }
}

impl clap::ValueEnum for MethodChoice {
    fn value_variants<'a>() -> &'a [Self] {
        &Self::ALL
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        let help = match self {
            MethodChoice::Auto => {
                "the best linear rung on held-out pairs, or the CompenNet++ rung the device \
                 affords (compennet++-res on the CPU, compennet++-res-full on a GPU) if it \
                 scores --climb-gain dB higher (train: on held-out pairs; calibrate and bench: \
                 in closed loop on the rig; evidence in model.json)"
            }
            MethodChoice::Rung(Method::Linear) => "learned affine+TPS geometry, per-pixel colour",
            MethodChoice::Rung(Method::LinearSl) => "structured-light geometry, per-pixel colour",
            MethodChoice::Rung(Method::CompenNetPpFaster) => "48 pairs, batch 16, 500 iterations",
            MethodChoice::Rung(Method::CompenNetPpFast) => "the paper's fast schedule",
            MethodChoice::Rung(Method::CompenNetPpNoRefine) => "no geometry refinement CNN",
            MethodChoice::Rung(Method::CompenNetPp) => "500 pairs, batch 48, 1500 iterations",
            MethodChoice::Rung(Method::CompenNetSl) => "CompenNet on the structured-light grid",
            MethodChoice::Rung(Method::CompenNetPpCpu) => {
                "the CPU-sized rung: half side, half widths, 1000 iterations of 4"
            }
            MethodChoice::Rung(Method::CompenNetPpRes) => {
                "linear plus a CPU-sized CompenNet correction that starts at zero"
            }
            MethodChoice::Rung(Method::CompenNetPpResFull) => {
                "linear plus a full-size CompenNet correction that starts at zero (for a GPU)"
            }
        };
        Some(clap::builder::PossibleValue::new(self.name()).help(help))
    }
}
