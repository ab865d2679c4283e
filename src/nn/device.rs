//! The device CompenNet++ training runs on (`train --device`): the CPU or a CUDA GPU through
//! candle. The training record ([`crate::record::TrainingRecord`]) names it.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// The device CompenNet++ training runs on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum TrainDevice {
    #[default]
    Cpu,
    /// An NVIDIA GPU by CUDA ordinal; needs a build with the `cuda` cargo feature.
    Cuda(usize),
}

impl std::str::FromStr for TrainDevice {
    type Err = Error;
    /// `cpu`, `cuda` (ordinal 0) or `cuda:N`.
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "cpu" => Ok(Self::Cpu),
            "cuda" => Ok(Self::Cuda(0)),
            _ => s
                .strip_prefix("cuda:")
                .and_then(|n| n.parse().ok())
                .map(Self::Cuda)
                .ok_or_else(|| {
                    Error::Input(format!(
                        "device `{s}`: expected `cpu`, `cuda` or `cuda:N` (N a GPU ordinal)"
                    ))
                }),
        }
    }
}

impl std::fmt::Display for TrainDevice {
    /// As written on the command line and in the configuration: `cpu` or `cuda:N`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Cpu => f.write_str("cpu"),
            Self::Cuda(n) => write!(f, "cuda:{n}"),
        }
    }
}

impl TrainDevice {
    /// The candle device; an input error when this build has no CUDA or the GPU cannot be opened.
    pub fn candle(self) -> Result<candle_core::Device> {
        match self {
            Self::Cpu => Ok(candle_core::Device::Cpu),
            Self::Cuda(_) if !cfg!(feature = "cuda") => Err(Error::Input(format!(
                "device `{self}`: this compend was built without CUDA; rebuild with `cargo \
                 build --release --features cuda` (needs the CUDA toolkit's nvcc)"
            ))),
            Self::Cuda(n) => candle_core::Device::new_cuda(n)
                .map_err(|e| Error::Input(format!("device `{self}`: cannot open GPU {n}: {e}"))),
        }
    }
}
