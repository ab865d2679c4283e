//! A set of projectors on one surface, seen by one camera: tiled side by side or stacked for
//! brightness ([`crate::rig::scene::Scene::more_projectors`]).
//!
//! Each projector is simulated on its own ([`Simulator`] of [`Scene::alone`]); light adds, so
//! the sensor signal of the set is the sum of each projector's (its emission, black level
//! included, through the geometry, the surface and the camera's linear optics), plus the
//! scene's constant light (ambient, glare) once; noise, clipping, the response curve and
//! quantisation follow on the sum, as in a single capture. Inter-reflection, sub-surface
//! scattering and the camera's blur are linear in the light, so summing after them is exact;
//! a white segment and an LCD's cross-talk act within each projector, before the sum.

use super::{Phase, Simulator};
use crate::error::{Error, Result};
use crate::raster::{CamImage, Camera, ImageSize, Mask, PrjImage};
use crate::rig::scene::Scene;

/// A scene's projectors simulated together. Immutable and `Sync`.
#[derive(Debug)]
pub struct SetSimulator {
    /// One simulator per projector, the scene's first projector first.
    sims: Vec<Simulator>,
    scene: Scene,
}

impl SetSimulator {
    /// Prepares every projector of `scene` (validated) with texture seed `seed`; `phase` moves
    /// the first projector only (the scene's drift). A projector whose light falls on no
    /// surface point the camera sees is refused, named.
    pub fn new(scene: &Scene, seed: u64, phase: Phase) -> Result<Self> {
        scene.validate()?;
        let sims = (0..scene.projectors().len())
            .map(|k| {
                let one = scene.alone(k).ok_or_else(|| {
                    Error::Failed(format!("scene {:?} has no projector {k}", scene.name))
                })?;
                Simulator::new(&one, seed, if k == 0 { phase } else { Phase::Calibration })
            })
            .collect::<Result<Vec<_>>>()?;
        for (k, sim) in sims.iter().enumerate() {
            if !sim.lit_mask().data().iter().any(|&v| v) {
                return Err(Error::Input(format!(
                    "scene {:?}: projector {} lights nothing the camera sees (aimed away from \
                     the surface, or outside the camera's view); turn it or the camera",
                    scene.name,
                    k + 1
                )));
            }
        }
        Ok(SetSimulator {
            sims,
            scene: scene.clone(),
        })
    }

    /// The scene and its projectors' simulators, the first projector's first.
    pub fn into_parts(self) -> (Scene, Vec<Simulator>) {
        (self.scene, self.sims)
    }

    /// The scene, with all its projectors.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The projectors' simulators, each alone on the surface.
    pub fn projectors(&self) -> &[Simulator] {
        &self.sims
    }

    pub fn camera_size(&self) -> ImageSize {
        self.sims[0].camera_size()
    }

    /// The noise-free sensor signal when projector k shows `images[k]` (linear, camera space,
    /// interleaved RGB, not clipped).
    pub fn clean_signal(&self, images: &[PrjImage]) -> Result<Vec<f32>> {
        self.check(images)?;
        let mut sum: Option<Vec<f32>> = None;
        for (sim, img) in self.sims.iter().zip(images) {
            sim.check_prj(img)?;
            let s = sim.sensor(&sim.emission(img));
            match &mut sum {
                None => sum = Some(s),
                Some(acc) => acc.iter_mut().zip(&s).for_each(|(a, b)| *a += b),
            }
        }
        let mut s = sum.unwrap_or_default();
        // Ambient light and glare are the room's, once whatever the projectors show.
        self.sims[0].add_constant(&mut s);
        Ok(s)
    }

    /// One capture of the set showing `images` (projector k shows `images[k]`): noise drawn
    /// from (seed, `frame`), clipped, encoded and quantised to 8-bit levels.
    pub fn capture(&self, images: &[PrjImage], frame: u64) -> Result<CamImage> {
        let s = self.clean_signal(images)?;
        Ok(self.sims[0].finish(&s, Some(frame)))
    }

    /// Noise-free camera output for `images`, without quantisation: clip and response only.
    pub fn expected(&self, images: &[PrjImage]) -> Result<CamImage> {
        let s = self.clean_signal(images)?;
        let inv = 1.0 / self.scene.camera.gamma as f32;
        let data = s.iter().map(|&v| v.clamp(0.0, 1.0).powf(inv)).collect();
        let ImageSize { width, height } = self.camera_size();
        CamImage::from_vec(width, height, data)
    }

    /// Every projector showing `level` (all channels), for captures such as white and black.
    pub fn uniform(&self, level: f32) -> Vec<PrjImage> {
        self.sims
            .iter()
            .map(|s| {
                let ImageSize { width, height } = s.projector_size();
                PrjImage::filled(width, height, [level; 3])
            })
            .collect()
    }

    /// Projector `k` (0: the scene's first) as a single-projector simulator that sees the set
    /// with every other projector black: its own light, the others' black levels through the
    /// scene, and the room's light. What calibrating the projectors one at a time captures;
    /// anything that takes one [`Simulator`] (the virtual rig's devices, the oracle) takes it.
    pub fn with_others_black(&self, k: usize) -> Result<Simulator> {
        let own = self.sims.get(k).ok_or_else(|| {
            Error::Input(format!(
                "scene {:?} has {} projectors, not a projector {}",
                self.scene.name,
                self.sims.len(),
                k + 1
            ))
        })?;
        let scene = self.scene.alone(k).ok_or_else(|| {
            Error::Failed(format!("scene {:?}: no projector {k}", self.scene.name))
        })?;
        let mut sim = Simulator::new(&scene, own.seed(), own.phase())?;
        let ImageSize { width, height } = self.camera_size();
        let mut others = vec![0f32; width * height * 3];
        for (_, other) in self.sims.iter().enumerate().filter(|(j, _)| *j != k) {
            let ImageSize {
                width: pw,
                height: ph,
            } = other.projector_size();
            let black = other.sensor(&other.emission(&PrjImage::new(pw, ph)));
            others.iter_mut().zip(&black).for_each(|(a, b)| *a += b);
        }
        sim.add_to_constant(&others);
        Ok(sim)
    }

    /// Camera pixels some projector of the set lights.
    pub fn lit_union(&self) -> Mask<Camera> {
        let masks: Vec<Mask<Camera>> = self.sims.iter().map(Simulator::lit_mask).collect();
        let ImageSize { width, height } = self.camera_size();
        let data = (0..width * height)
            .map(|i| masks.iter().any(|m| m.data()[i]))
            .collect();
        Mask::from_vec(width, height, data).expect("one entry per camera pixel")
    }

    /// Camera pixels two or more projectors light: where a tiled set overlaps.
    pub fn overlap(&self) -> Mask<Camera> {
        let masks: Vec<Mask<Camera>> = self.sims.iter().map(Simulator::lit_mask).collect();
        let ImageSize { width, height } = self.camera_size();
        let data = (0..width * height)
            .map(|i| masks.iter().filter(|m| m.data()[i]).count() >= 2)
            .collect();
        Mask::from_vec(width, height, data).expect("one entry per camera pixel")
    }

    /// Where a seam would show, inside `region` (camera pixels), from where each projector's
    /// light falls ([`crate::joint::seam_regions`]).
    pub fn seam_regions(
        &self,
        region: &Mask<Camera>,
        band_px: usize,
    ) -> (Mask<Camera>, Mask<Camera>) {
        let masks: Vec<Mask<Camera>> = self.sims.iter().map(Simulator::lit_mask).collect();
        crate::joint::seam_regions(&masks, region, band_px)
    }

    fn check(&self, images: &[PrjImage]) -> Result<()> {
        if images.len() != self.sims.len() {
            return Err(Error::Shape(format!(
                "scene {:?} has {} projectors, {} images were given",
                self.scene.name,
                self.sims.len(),
                images.len()
            )));
        }
        Ok(())
    }
}
