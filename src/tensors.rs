//! Named f32 arrays with their shapes, and their safetensors encoding (f32, little-endian): the
//! container a model's weights are saved in ([`crate::model::store`]) and pretrained weights are
//! read from ([`crate::nn::pretrain`]).

use std::collections::BTreeMap;
use std::path::Path;

use safetensors::tensor::{Dtype, TensorView};

use crate::error::{Error, Result};

/// Named f32 arrays with shapes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Tensors {
    map: BTreeMap<String, (Vec<usize>, Vec<f32>)>,
}

impl Tensors {
    pub fn insert(&mut self, name: &str, shape: Vec<usize>, data: Vec<f32>) -> Result<()> {
        let n: usize = shape.iter().product();
        if n != data.len() {
            return Err(Error::Shape(format!(
                "tensor {name}: shape {shape:?} needs {n} values, got {}",
                data.len()
            )));
        }
        self.map.insert(name.to_string(), (shape, data));
        Ok(())
    }

    /// The tensor `name`, checked against the expected shape; `file` names the source in errors.
    pub fn get(&self, name: &str, shape: &[usize], file: &Path) -> Result<&[f32]> {
        match self.map.get(name) {
            None => Err(Error::Input(format!(
                "{}: tensor `{name}` is missing (expected shape {shape:?})",
                file.display()
            ))),
            Some((s, _)) if s.as_slice() != shape => Err(Error::Input(format!(
                "{}: tensor `{name}` has shape {s:?}, expected {shape:?}",
                file.display()
            ))),
            Some((_, d)) => Ok(d),
        }
    }

    /// The stored shape of `name`, if present.
    pub fn shape(&self, name: &str) -> Option<&[usize]> {
        self.map.get(name).map(|(shape, _)| shape.as_slice())
    }

    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.map.keys().map(|s| s.as_str())
    }

    /// Adds every tensor of `other` under `prefix` + its name (a part of a composite model).
    pub fn insert_all(&mut self, prefix: &str, other: Tensors) {
        for (k, v) in other.map {
            self.map.insert(format!("{prefix}{k}"), v);
        }
    }

    /// The tensors named `prefix` + something, named by the something.
    pub fn under(&self, prefix: &str) -> Tensors {
        Tensors {
            map: self
                .map
                .iter()
                .filter_map(|(k, v)| Some((k.strip_prefix(prefix)?.to_string(), v.clone())))
                .collect(),
        }
    }

    /// The arrays as a safetensors file's bytes (f32, little-endian). On a little-endian
    /// machine the arrays are serialised from where they lie, without a second copy of every
    /// weight (the `linear` rung's 1920×1080 lattice is 100 MB of them).
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        let bytes: Vec<std::borrow::Cow<'_, [u8]>> =
            self.map.values().map(|(_, d)| le_bytes(d)).collect();
        let views = (self.map.iter().zip(&bytes))
            .map(|((k, (s, _)), b)| {
                TensorView::new(Dtype::F32, s.clone(), b)
                    .map(|v| (k.clone(), v))
                    .map_err(|e| Error::Shape(format!("tensor {k}: {e}")))
            })
            .collect::<Result<Vec<_>>>()?;
        safetensors::serialize(views, None)
            .map_err(|e| Error::Failed(format!("safetensors encoding failed: {e}")))
    }

    /// Parses a safetensors file's bytes (f32 arrays only); `file` names the source in errors.
    pub fn from_bytes(bytes: &[u8], file: &Path) -> Result<Self> {
        let st = safetensors::SafeTensors::deserialize(bytes).map_err(|e| {
            Error::Input(format!(
                "{}: not a readable safetensors file ({e})",
                file.display()
            ))
        })?;
        let mut out = Tensors::default();
        for (name, view) in st.tensors() {
            if view.dtype() != Dtype::F32 {
                return Err(Error::Input(format!(
                    "{}: tensor `{name}` is {:?}, expected F32",
                    file.display(),
                    view.dtype()
                )));
            }
            let data = view
                .data()
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            out.map.insert(name, (view.shape().to_vec(), data));
        }
        Ok(out)
    }
}

/// f32 values as little-endian bytes: where they lie on a little-endian machine.
fn le_bytes(values: &[f32]) -> std::borrow::Cow<'_, [u8]> {
    if cfg!(target_endian = "little") {
        std::borrow::Cow::Borrowed(bytemuck::cast_slice(values))
    } else {
        std::borrow::Cow::Owned(values.iter().flat_map(|v| v.to_le_bytes()).collect())
    }
}
