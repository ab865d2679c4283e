//! `[output]`: the compensated frames to other software as well as the projector.

use serde::Serialize;

use super::read::{Table, Walker};

/// `[output]`: the compensated frames to other software as well as the projector.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct OutputConfig {
    /// `file:PATH` (each playback to `NAME-NNNN.EXT` beside it) or `gst:PIPELINE`; None: off.
    #[serde(serialize_with = "output_or_none")]
    pub to: Option<crate::output::OutputSpec>,
}

pub(super) fn output_or_none<S: serde::Serializer>(
    v: &Option<crate::output::OutputSpec>,
    s: S,
) -> std::result::Result<S::Ok, S::Error> {
    match v {
        Some(o) => s.collect_str(o),
        None => s.serialize_str("none"),
    }
}

impl OutputConfig {
    /// Off unless `to` names where.
    pub(super) fn read<'t>(w: &mut Walker<'t>, t: &mut Table<'t>) -> Self {
        OutputConfig {
            to: w.parsed_with(t, "to", |s| {
                crate::output::OutputSpec::parse(s).map_err(|e| e.to_string())
            }),
        }
    }
}
