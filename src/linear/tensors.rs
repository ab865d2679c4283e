//! The `linear` model in the model directory (docs/architecture.md, "Model directory"): its
//! numeric state as named tensors, and the checks made when reading them back.

use super::model::{Coefficients, Curves, Geometry, LinearModel};
use crate::error::{Error, Result};
use crate::raster::ImageSize;
use crate::sample::Grid;
use crate::warp::{OffsetField, Warp};

impl LinearModel {
    /// Numeric state for the model directory: the learnable geometry, the baked grid (what playback
    /// reads), the curves and the per-pixel coefficients.
    pub fn to_tensors(&self) -> Result<crate::tensors::Tensors> {
        let ImageSize {
            width: w,
            height: h,
        } = self.network_size();
        let mut t = crate::tensors::Tensors::default();
        if let Geometry::Learned(warp, refine) = &self.geometry {
            let theta = warp.theta.iter().flatten().copied().collect();
            t.insert("warp.theta", vec![2, 3], theta)?;
            let tps: Vec<f32> = warp.tps.iter().flatten().copied().collect();
            t.insert("warp.tps", vec![2, crate::warp::TPS_PARAMS], tps)?;
            if let Some(f) = refine {
                t.insert("warp.refine", vec![f.height, f.width, 2], f.to_params())?;
            }
            if self.geometry_size != self.network_size() {
                let ImageSize {
                    width: gw,
                    height: gh,
                } = self.geometry_size;
                t.insert("warp.network", vec![2], vec![gw as f32, gh as f32])?;
            }
        }
        let grid = self.grid();
        t.insert(
            "grid",
            vec![h, w, 2],
            grid.data().iter().flatten().copied().collect(),
        )?;
        t.insert(
            "curves.camera_gamma",
            vec![3],
            self.curves.camera_gamma.to_vec(),
        )?;
        t.insert(
            "curves.projector_gamma",
            vec![3],
            self.curves.projector_gamma.to_vec(),
        )?;
        t.insert(
            "colour.coeffs",
            vec![h, w, 12],
            self.coeffs.data.iter().flatten().copied().collect(),
        )?;
        Ok(t)
    }

    /// Rebuilds a model from the model directory's tensors; `file` names the weights in errors.
    /// `network_size` is the coefficients' lattice (network pixels), `camera_size` the camera
    /// image size (camera pixels) the geometry refers to.
    pub fn from_tensors(
        t: &crate::tensors::Tensors,
        network_size: ImageSize,
        camera_size: ImageSize,
        file: &std::path::Path,
    ) -> Result<Self> {
        let ImageSize {
            width: w,
            height: h,
        } = network_size;
        let cg = t.get("curves.camera_gamma", &[3], file)?;
        let pg = t.get("curves.projector_gamma", &[3], file)?;
        let co = t.get("colour.coeffs", &[h, w, 12], file)?;
        let grid = t.get("grid", &[h, w, 2], file)?;
        if grid.iter().chain(co).any(|v| !v.is_finite()) {
            return Err(bad(file, "grid/colour.coeffs"));
        }
        if cg
            .iter()
            .chain(pg)
            .any(|&g| !(g.is_finite() && g > 0.05 && g < 20.0))
        {
            return Err(bad(file, "curves"));
        }
        let geometry_size = read_geometry_size(t, network_size, file)?;
        // A learned model carries its warp parameters; a fixed-geometry one only the grid.
        let geometry = if t.names().any(|n| n == "warp.theta") {
            read_learned(t, file)?
        } else {
            let cells = grid.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
            Geometry::Fixed(Grid::from_vec(w, h, cells)?)
        };
        let data = co
            .chunks_exact(12)
            .map(|c| {
                let mut k = [0f32; 12];
                k.copy_from_slice(c);
                k
            })
            .collect();
        Ok(Self {
            geometry,
            curves: Curves {
                camera_gamma: [cg[0], cg[1], cg[2]],
                projector_gamma: [pg[0], pg[1], pg[2]],
            },
            coeffs: Coefficients {
                width: w,
                height: h,
                data,
            },
            camera_size,
            geometry_size,
        })
    }
}

/// The error for a tensor of `file` whose values are non-finite or out of range.
fn bad(file: &std::path::Path, name: &str) -> Error {
    Error::Input(format!(
        "{}: tensor `{name}` holds non-finite or out-of-range values",
        file.display()
    ))
}

/// The network size a learned geometry was fitted at (network pixels): `warp.network` when
/// present, else the lattice size `(w, h)`. A learned geometry fitted on a coarser network than
/// the lattice says so; earlier models (and every fixed geometry) have one size for both.
fn read_geometry_size(
    t: &crate::tensors::Tensors,
    network_size: ImageSize,
    file: &std::path::Path,
) -> Result<ImageSize> {
    Ok(match t.shape("warp.network") {
        None => network_size,
        Some(_) => {
            let v = t.get("warp.network", &[2], file)?;
            let side =
                |x: f32| (x.is_finite() && (2.0..=65_536.0).contains(&x)).then_some(x as usize);
            match (side(v[0]), side(v[1])) {
                (Some(gw), Some(gh)) => ImageSize::new(gw, gh),
                _ => return Err(bad(file, "warp.network")),
            }
        }
    })
}

/// A learned geometry: the affine + TPS parameters (normalised coordinates) and the optional
/// dense refinement field.
fn read_learned(t: &crate::tensors::Tensors, file: &std::path::Path) -> Result<Geometry> {
    let th = t.get("warp.theta", &[2, 3], file)?;
    let tps = t.get("warp.tps", &[2, crate::warp::TPS_PARAMS], file)?;
    if th.iter().chain(tps).any(|v| !v.is_finite()) {
        return Err(bad(file, "warp"));
    }
    let refine = read_refine(t, file)?;
    Ok(Geometry::Learned(
        Warp {
            theta: [[th[0], th[1], th[2]], [th[3], th[4], th[5]]],
            tps: [
                tps[..crate::warp::TPS_PARAMS].to_vec(),
                tps[crate::warp::TPS_PARAMS..].to_vec(),
            ],
        },
        refine,
    ))
}

/// The dense refinement field `warp.refine` ([rows, columns, 2] offsets in normalised camera
/// coordinates), when present.
fn read_refine(t: &crate::tensors::Tensors, file: &std::path::Path) -> Result<Option<OffsetField>> {
    Ok(match t.shape("warp.refine") {
        None => None,
        Some(&[fh, fw, 2]) if fw >= 2 && fh >= 2 => {
            let v = t.get("warp.refine", &[fh, fw, 2], file)?;
            if v.iter().any(|x| !x.is_finite()) {
                return Err(bad(file, "warp.refine"));
            }
            let mut f = OffsetField::zeros(fw, fh);
            f.set_params(v);
            Some(f)
        }
        Some(other) => {
            return Err(Error::Input(format!(
                "{}: tensor `warp.refine` has shape {other:?}, expected [rows, columns, 2] \
                 with at least 2 rows and columns",
                file.display()
            )));
        }
    })
}
