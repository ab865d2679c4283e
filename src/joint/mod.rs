//! Joint compensation of a set of projectors on one surface (docs/architecture.md, "Sets of
//! projectors"): the desired view split among the projectors that reach each point, each
//! compensated for the surface and for the others' light, from each projector's own `linear`
//! model fitted with the others black.
//!
//! Formulation. Projector j's model says that at a camera point its light `ℓ_j` (projector
//! linear, in [0, 1]³) is seen as camera linear light `A_j ℓ_j + e`, `A_j = M_j⁻¹`, where `e`
//! is what the camera sees with every projector black (the room's light and all the black
//! levels: each model was fitted with the others black, so its offset holds theirs). Light
//! adds, so with all projecting the camera sees `Σ_j A_j ℓ_j + e`. For the desired value `z`
//! (camera-encoded; `a* = z^γc` linear) the projectors' light is
//!
//! `argmin over ℓ in [0, 1]^{3n} of ‖W (Σ_j A_j ℓ_j + e − a*)‖² + λ Σ_j ‖ℓ_j − ℓ⁰_j‖²`,
//!
//! with `ℓ⁰_j = M_j (s_j (a* − e))`, the blended split: projector j alone giving its share
//! `s_j` of the view above black. The shares are smooth across the overlaps (each projector's
//! distance to the edge of its cover, squared, times its smoothed brightness there,
//! normalised: [`blend`]) and read by every projector from the same camera-space maps, so where the split is in range it is the exact answer and the picture has no
//! seam; where one projector's share is out of range (too bright for it, or a colour outside
//! its gamut there) the least-squares term moves the difference onto the others' light, which
//! is how a stacked set reaches what one projector cannot. `W` weights the channels by the
//! camera encoding's slope as `linear::gamut` does, so the error is what PSNR measures; the
//! small `λ` keeps the split where many splits give the same view. The bounded problem (3n
//! unknowns, n ≤ [`MAX_PROJECTORS`]) is solved exactly by a primal active-set method started
//! from the clamped split ([`solve`]).
//!
//! Where one projector alone reaches a point its share is 1 and the solve is `linear`'s own
//! compensation with its gamut map (up to `λ`), so a set whose projectors do not overlap is
//! each compensated as alone.
//!
//! Each projector's output is computed on its own lattice (network pixels): at lattice pixel
//! `p` it looks up the camera point its grid gives, the other projectors' colour models there
//! (their lattice positions from their [`cover::Cover`], their coefficients interpolated),
//! solves the joint problem and keeps its own light. Every projector solves the same problem
//! at a point (terms in projector order), so their answers agree where their pixels meet.
//!
//! Spaces: desired views are camera images (camera pixels, encoded values); outputs are each
//! projector's network images (projector input values).

pub mod blend;
pub mod cover;
pub mod seam;
pub mod solve;

use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::linear::{Coefficients, SimplifiedLinear};
use crate::raster::{CamImage, Camera, ImageSize, Mask, NetImage};
use crate::sample::norm_to_pixel;

pub use cover::Cover;
pub use seam::seam_regions;
pub use solve::{MAX_PROJECTORS, Term};

/// What the joint pass reads per lattice pixel and projector slot: lattice x, y and share (x
/// below 0 where the projector does not reach).
pub const SLOT_FLOATS: usize = 3;

/// Where a projector of the set is seen from one lattice pixel of another (or its own): its
/// lattice position at that camera point (network pixels of its lattice) and its share there.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Slot {
    pub at: [f32; 2],
    pub share: f32,
}

/// One projector's part of the joint model, on its lattice.
#[derive(Clone, Debug)]
struct Part {
    model: SimplifiedLinear,
    /// Per lattice pixel and projector of the set (in order): where that projector is seen at
    /// the camera point this pixel lights; `None` where it does not reach (always `Some` for
    /// this part's own projector, at the pixel itself, where the point is in the camera image).
    slots: Vec<[Option<Slot>; MAX_PROJECTORS]>,
}

/// A set's joint model: each projector's `linear` model and where the others reach it.
#[derive(Clone, Debug)]
pub struct JointModel {
    parts: Vec<Part>,
    covers: Vec<Cover>,
    camera: ImageSize,
}

impl JointModel {
    /// The joint model of projectors whose `linear` models (fitted one at a time with the others
    /// black, the same camera at the same exposure) are `models`, the set's first first, on a
    /// camera of `camera` pixels.
    pub fn new(models: Vec<SimplifiedLinear>, camera: ImageSize) -> Result<Self> {
        if models.is_empty() || models.len() > MAX_PROJECTORS {
            return Err(Error::Input(format!(
                "a set of {} projectors: joint compensation takes 1 to {MAX_PROJECTORS}",
                models.len()
            )));
        }
        let covers: Vec<Cover> = models
            .par_iter()
            .map(|m| Cover::of(&m.grid, camera))
            .collect();
        for (k, c) in covers.iter().enumerate() {
            if !(0..camera.width * camera.height).any(|i| c.covers(i)) {
                return Err(Error::Input(format!(
                    "projector {}'s model reaches no pixel of the {camera} camera image",
                    k + 1
                )));
            }
        }
        let bright: Vec<Vec<f32>> = models
            .par_iter()
            .zip(&covers)
            .map(|(m, c)| {
                (0..camera.width * camera.height)
                    .map(|i| {
                        c.lattice_of(i).map_or(0.0, |[x, y]| {
                            blend::brightness(&coefficients_at(&m.coeffs, x, y))
                        })
                    })
                    .collect()
            })
            .collect();
        let shares = blend::share_maps(&covers, &bright, camera);
        let parts = (0..models.len())
            .map(|k| Part {
                slots: part_slots(k, &models, (&covers, &shares), camera),
                model: models[k].clone(),
            })
            .collect();
        Ok(JointModel {
            parts,
            covers,
            camera,
        })
    }

    pub fn projectors(&self) -> usize {
        self.parts.len()
    }

    /// Projector `k`'s own model.
    pub fn model(&self, k: usize) -> Option<&SimplifiedLinear> {
        self.parts.get(k).map(|p| &p.model)
    }

    pub fn camera_size(&self) -> ImageSize {
        self.camera
    }

    /// Projector `k`'s slots (per lattice pixel, per projector of the set): what its pass reads.
    pub fn slots(&self, k: usize) -> Option<&[[Option<Slot>; MAX_PROJECTORS]]> {
        self.parts.get(k).map(|p| p.slots.as_slice())
    }

    /// The camera pixels projector `k` reaches in its model.
    pub fn cover(&self, k: usize) -> Option<&Cover> {
        self.covers.get(k)
    }

    /// The camera pixels two or more projectors reach.
    pub fn overlap(&self) -> Mask<Camera> {
        let ImageSize { width, height } = self.camera;
        Mask::from_fn(width, height, |x, y| {
            let i = y * width + x;
            self.covers.iter().filter(|c| c.covers(i)).count() >= 2
        })
    }

    /// The CPU reference of the joint pass: every projector's image (its network lattice,
    /// projector input values) for the desired camera view `desired` (camera pixels, encoded).
    pub fn apply(&self, desired: &CamImage) -> Result<Vec<NetImage>> {
        if desired.size() != self.camera {
            return Err(Error::Shape(format!(
                "a {} desired view for a set calibrated with a {} camera",
                desired.size(),
                self.camera
            )));
        }
        Ok((0..self.parts.len())
            .map(|k| self.apply_one(k, desired))
            .collect())
    }

    fn apply_one(&self, k: usize, desired: &CamImage) -> NetImage {
        let part = &self.parts[k];
        let curves = part.model.curves;
        let inv_gamma = part.model.curves.projector_gamma.map(|g| 1.0 / g);
        let mut out = crate::sample::grid_sample(desired, &part.model.grid);
        out.data_mut()
            .par_chunks_exact_mut(3)
            .zip(part.slots.par_iter())
            .for_each(|(px, slots)| {
                let mut terms = [Term {
                    coeffs: [0.0; 12],
                    share: 0.0,
                }; MAX_PROJECTORS];
                let (mut n, mut own) = (0, None);
                for (j, slot) in slots.iter().enumerate() {
                    if let Some(s) = slot {
                        if j == k {
                            own = Some(n);
                        }
                        let [x, y] = s.at;
                        terms[n] = Term {
                            coeffs: coefficients_at(&self.parts[j].model.coeffs, x, y),
                            share: s.share,
                        };
                        n += 1;
                    }
                }
                let Some(own) = own else {
                    px.fill(0.0);
                    return;
                };
                let z = [px[0], px[1], px[2]];
                let light = solve::solve(&terms[..n], own, z, curves.camera_gamma);
                for c in 0..3 {
                    px[c] = pow0(light[own][c].clamp(0.0, 1.0), inv_gamma[c]);
                }
            });
        out
    }
}

/// `x^g` for `x > 0`, else 0 (as the shaders' `pow0`).
fn pow0(x: f32, g: f32) -> f32 {
    if x > 0.0 { x.powf(g) } else { 0.0 }
}

/// The slots of projector `k`'s lattice pixels: at the camera point each lights, every
/// projector that reaches it with its lattice position there and its share (from the
/// camera-space share maps, renormalised over those that reach it).
fn part_slots(
    k: usize,
    models: &[SimplifiedLinear],
    (covers, shares): (&[Cover], &[Vec<f32>]),
    camera: ImageSize,
) -> Vec<[Option<Slot>; MAX_PROJECTORS]> {
    let own = &models[k];
    let width = own.grid.width();
    own.grid
        .data()
        .par_iter()
        .enumerate()
        .map(|(p, &[gx, gy])| {
            let (u, v) = (
                norm_to_pixel(gx, camera.width),
                norm_to_pixel(gy, camera.height),
            );
            let mut slots = [None; MAX_PROJECTORS];
            let inside = u >= -0.5
                && v >= -0.5
                && u <= camera.width as f32 - 0.5
                && v <= camera.height as f32 - 0.5;
            if !inside {
                return slots;
            }
            let mut at = [None; MAX_PROJECTORS];
            let mut present = [false; MAX_PROJECTORS];
            let mut read = [0f32; MAX_PROJECTORS];
            for (j, cover) in covers.iter().enumerate() {
                at[j] = if j == k {
                    Some([(p % width) as f32, (p / width) as f32])
                } else {
                    cover.lattice_at(u, v)
                };
                present[j] = at[j].is_some();
                read[j] = cover.bilinear(&shares[j], u, v);
            }
            let share = blend::renormalise(read, present);
            for j in 0..models.len() {
                slots[j] = at[j].map(|at| Slot {
                    at,
                    share: share[j],
                });
            }
            slots
        })
        .collect()
}

/// Coefficients at lattice position (x, y), bilinear between the four lattice pixels around it
/// (clamped to the lattice); at a lattice pixel, its own.
pub fn coefficients_at(c: &Coefficients, x: f32, y: f32) -> [f32; 12] {
    let (w, h) = (c.width, c.height);
    let x = x.clamp(0.0, (w - 1) as f32);
    let y = y.clamp(0.0, (h - 1) as f32);
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let mut out = [0f32; 12];
    for (xi, yi, wt) in [
        (x0, y0, (1.0 - fx) * (1.0 - fy)),
        (x1, y0, fx * (1.0 - fy)),
        (x0, y1, (1.0 - fx) * fy),
        (x1, y1, fx * fy),
    ] {
        let k = &c.data[yi * w + xi];
        for (o, v) in out.iter_mut().zip(k) {
            *o += wt * v;
        }
    }
    out
}
