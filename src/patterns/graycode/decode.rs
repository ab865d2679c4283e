//! The decoder of the Gray-code sequence: captures (camera pixels, RGB in \[0,1\]) to a dense
//! camera → projector correspondence (projector pixels, centres at integers). The thresholds and
//! the boundary rule are described in [`super`].

use super::{GrayCode, PatternKind, from_gray};
use crate::error::{Error, Result};
use crate::raster::{CamImage, Camera, ImageSize, Mask, Plane, Projector};

/// Thresholds of the decoder. Intensities are channel means of captures in \[0,1\].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DecodeParams {
    /// A pixel is lit where `white − black > max(lit_abs, lit_rel · L)`, `L` being the 99th
    /// percentile of `white − black` over the capture (its lit range).
    pub lit_abs: f32,
    pub lit_rel: f32,
    /// A bit is decided where `|pattern − inverse| > max(bit_abs, bit_rel · (white − black))` at
    /// that pixel.
    pub bit_abs: f32,
    pub bit_rel: f32,
    /// Accept one undecided bit per axis where the two codes it leaves open are neighbouring
    /// columns (rows): the pixel straddles the boundary between them, the one place where a Gray
    /// code is legitimately ambiguous. The coordinate is then their midpoint (`n + 0.5`). Without
    /// this, a camera coarser than the projector, or blur, loses many pixels to the finest bits
    /// (a fifth to most of them in the tests' synthetic rig).
    pub accept_boundary: bool,
}

impl Default for DecodeParams {
    /// Defaults: lit above max(0.04, 0.1·L) — about 10/255, or a tenth of the lit range, which
    /// keeps dark surface areas while rejecting unlit ones where only noise differs; bits decided
    /// above max(0.01, 0.05·(white − black)) — 0.01 ≈ 2.5/255, about the noise of a difference
    /// of two 8-bit captures, and far below the contrast a bit has away from stripe edges; one
    /// boundary bit per axis accepted.
    fn default() -> Self {
        Self {
            lit_abs: 0.04,
            lit_rel: 0.1,
            bit_abs: 0.01,
            bit_rel: 0.05,
            accept_boundary: true,
        }
    }
}

impl DecodeParams {
    /// The lit threshold for a capture whose white − black 99th percentile is `lit_range`.
    pub fn lit_threshold(&self, lit_range: f32) -> f32 {
        self.lit_abs.max(self.lit_rel * lit_range)
    }
    /// The bit threshold at a pixel whose white − black difference is `contrast`.
    pub fn bit_threshold(&self, contrast: f32) -> f32 {
        self.bit_abs.max(self.bit_rel * contrast)
    }
}

/// A dense camera → projector correspondence map decoded from structured light.
#[derive(Clone, Debug)]
pub struct Correspondence {
    /// Projector (width, height) in pixels.
    pub projector: ImageSize,
    /// Projector column seen by each camera pixel (projector pixels, centres at integers); 0 where
    /// invalid.
    pub x: Plane<Camera>,
    /// Projector row seen by each camera pixel; 0 where invalid.
    pub y: Plane<Camera>,
    /// Camera pixels with a decoded, in-range correspondence.
    pub valid: Mask<Camera>,
    /// Camera pixels lit by the projector (white − black above the lit threshold); a superset of
    /// `valid`.
    pub lit: Mask<Camera>,
    /// White − black capture difference (channel mean), the projector's contrast per camera pixel.
    pub contrast: Plane<Camera>,
}

impl Correspondence {
    /// Camera (width, height) in pixels.
    pub fn size(&self) -> ImageSize {
        self.valid.size()
    }

    /// The projector pixel `(x, y)` seen at camera pixel `(cx, cy)`, if decoded.
    pub fn get(&self, cx: usize, cy: usize) -> Option<[f32; 2]> {
        self.valid
            .get(cx, cy)
            .then(|| [self.x.get(cx, cy), self.y.get(cx, cy)])
    }

    /// The inverse map, projector → camera: for every projector pixel the mean camera position
    /// (camera pixels, centres at integers) of the valid camera pixels that decoded to it (a
    /// camera pixel on a boundary, at `n + 0.5`, counts for both `n` and `n + 1`), and a mask of
    /// projector pixels seen by at least one camera pixel. No hole filling: where the camera
    /// sees a projector pixel through no camera pixel (e.g. the camera is coarser than the
    /// projector), the mask is false.
    pub fn projector_to_camera(&self) -> (Plane<Projector>, Plane<Projector>, Mask<Projector>) {
        let ImageSize {
            width: pw,
            height: ph,
        } = self.projector;
        let mut sx = vec![0f64; pw * ph];
        let mut sy = vec![0f64; pw * ph];
        let mut n = vec![0u32; pw * ph];
        let ImageSize {
            width: cw,
            height: ch,
        } = self.size();
        for cy in 0..ch {
            for cx in 0..cw {
                if let Some([px, py]) = self.get(cx, cy) {
                    // Coordinates are whole or halves; a half touches both neighbours.
                    let xs = [px.floor() as usize, (px.ceil() as usize).min(pw - 1)];
                    let ys = [py.floor() as usize, (py.ceil() as usize).min(ph - 1)];
                    for (j, &y) in ys.iter().enumerate() {
                        for (k, &x) in xs.iter().enumerate() {
                            if (j == 1 && ys[1] == ys[0]) || (k == 1 && xs[1] == xs[0]) {
                                continue;
                            }
                            let i = y * pw + x;
                            sx[i] += cx as f64;
                            sy[i] += cy as f64;
                            n[i] += 1;
                        }
                    }
                }
            }
        }
        let mean = |s: &[f64]| {
            Plane::from_fn(pw, ph, |x, y| {
                let i = y * pw + x;
                if n[i] > 0 {
                    (s[i] / n[i] as f64) as f32
                } else {
                    0.0
                }
            })
        };
        let mask = Mask::from_fn(pw, ph, |x, y| n[y * pw + x] > 0);
        (mean(&sx), mean(&sy), mask)
    }
}

/// Incremental decoder: push the captures one at a time, in sequence order, then `finish`.
/// Holds only the white and black captures, the pending pattern of a pair and the bits decoded
/// so far, so a live capture loop need not keep every frame.
#[derive(Clone, Debug)]
pub struct Decoder {
    code: GrayCode,
    params: DecodeParams,
    width: usize,
    height: usize,
    next: usize,
    white: Vec<f32>,
    contrast: Vec<f32>,
    /// The pattern image of the pair whose inverse comes next.
    pending: Vec<f32>,
    /// Gray codes accumulated so far, MSB first.
    col_gray: Vec<u32>,
    row_gray: Vec<u32>,
    /// Per pixel and axis: the undecided bit (its position counted from the least significant,
    /// plus one), `NONE` for none, `MANY` for more than one.
    col_open: Vec<u8>,
    row_open: Vec<u8>,
}

const NONE: u8 = 0;
const MANY: u8 = u8::MAX;

impl Decoder {
    /// A decoder for captures of `width × height` camera pixels.
    pub fn new(code: GrayCode, width: usize, height: usize, params: DecodeParams) -> Self {
        let n = width * height;
        Self {
            code,
            params,
            width,
            height,
            next: 0,
            white: Vec::new(),
            contrast: Vec::new(),
            pending: Vec::new(),
            col_gray: vec![0; n],
            row_gray: vec![0; n],
            col_open: vec![NONE; n],
            row_open: vec![NONE; n],
        }
    }

    /// Index (0-based) of the capture expected next.
    pub fn next_index(&self) -> usize {
        self.next
    }

    /// Adds the capture of pattern `next_index()`.
    pub fn push(&mut self, capture: &CamImage) -> Result<()> {
        let index = self.next;
        let kind = self.code.kind(index).ok_or_else(|| {
            Error::Input(format!(
                "structured light: capture {} is one too many (the sequence has {} images)",
                index + 1,
                self.code.len()
            ))
        })?;
        if capture.size() != ImageSize::new(self.width, self.height) {
            return Err(Error::Shape(format!(
                "structured light capture {} is {}, the first was {}x{}",
                index + 1,
                capture.size(),
                self.width,
                self.height
            )));
        }
        let v: Vec<f32> = capture
            .data()
            .chunks_exact(3)
            .map(|p| (p[0] + p[1] + p[2]) / 3.0)
            .collect();
        match kind {
            PatternKind::White => self.white = v,
            PatternKind::Black => {
                self.contrast = self.white.iter().zip(&v).map(|(w, b)| w - b).collect();
                self.white = Vec::new();
            }
            PatternKind::Column {
                inverted: false, ..
            }
            | PatternKind::Row {
                inverted: false, ..
            } => self.pending = v,
            PatternKind::Column {
                bit,
                inverted: true,
            }
            | PatternKind::Row {
                bit,
                inverted: true,
            } => {
                let (gray, open, bits) = if matches!(kind, PatternKind::Column { .. }) {
                    (&mut self.col_gray, &mut self.col_open, self.code.col_bits)
                } else {
                    (&mut self.row_gray, &mut self.row_open, self.code.row_bits)
                };
                // Position of this bit counted from the least significant, plus one.
                let tag = (bits - bit) as u8;
                for i in 0..v.len() {
                    let d = self.pending[i] - v[i];
                    gray[i] = (gray[i] << 1) | (d > 0.0) as u32;
                    if d.abs() <= self.params.bit_threshold(self.contrast[i]) {
                        open[i] = if open[i] == NONE { tag } else { MANY };
                    }
                }
                self.pending = Vec::new();
            }
        }
        self.next += 1;
        Ok(())
    }

    /// The correspondence map, once every capture has been pushed. Fails when no camera pixel is
    /// lit (the projector is not in view, or the white and black captures are swapped).
    pub fn finish(self) -> Result<Correspondence> {
        if self.next != self.code.len() {
            return Err(Error::Input(format!(
                "structured light: got {} captures, the sequence needs {}",
                self.next,
                self.code.len()
            )));
        }
        let (w, h) = (self.width, self.height);
        let lit_range = quantile(&self.contrast, 0.99);
        let lit_t = self.params.lit_threshold(lit_range);
        if lit_range <= lit_t {
            return Err(Error::Failed(format!(
                "structured light: nothing lit — white − black reaches only {lit_range:.4} \
                 (99th percentile), below the threshold {lit_t:.4}; is the projector in the camera view?"
            )));
        }
        let ImageSize {
            width: pw,
            height: ph,
        } = self.code.size();
        let n = w * h;
        let mut xs = vec![0f32; n];
        let mut ys = vec![0f32; n];
        let mut valid = vec![false; n];
        let mut lit = vec![false; n];
        for i in 0..n {
            lit[i] = self.contrast[i] > lit_t;
            if !lit[i] {
                continue;
            }
            let accept = self.params.accept_boundary;
            let x = resolve(self.col_gray[i], self.col_open[i], pw, accept);
            let y = resolve(self.row_gray[i], self.row_open[i], ph, accept);
            if let (Some(x), Some(y)) = (x, y) {
                xs[i] = x;
                ys[i] = y;
                valid[i] = true;
            }
        }
        Ok(Correspondence {
            projector: ImageSize::new(pw, ph),
            x: Plane::from_vec(w, h, xs)?,
            y: Plane::from_vec(w, h, ys)?,
            valid: Mask::from_vec(w, h, valid)?,
            lit: Mask::from_vec(w, h, lit)?,
            contrast: Plane::from_vec(w, h, self.contrast)?,
        })
    }
}

/// The coordinate encoded by `gray` on an axis of `n` pixels, given its undecided bit `open`
/// (see [`Decoder`]): the decoded value when every bit was decided; the midpoint of the two
/// neighbouring values a single undecided bit leaves open (or the one inside `0..n` when the
/// other is not), when `accept_boundary`; `None` otherwise or when out of range.
fn resolve(gray: u32, open: u8, n: usize, accept_boundary: bool) -> Option<f32> {
    let a = from_gray(gray) as usize;
    match open {
        NONE => (a < n).then_some(a as f32),
        MANY => None,
        _ if !accept_boundary => None,
        k => {
            let b = from_gray(gray ^ (1 << (k - 1))) as usize;
            if a.abs_diff(b) != 1 {
                return None;
            }
            match (a < n, b < n) {
                (true, true) => Some((a.min(b) as f32) + 0.5),
                (true, false) => Some(a as f32),
                (false, true) => Some(b as f32),
                (false, false) => None,
            }
        }
    }
}

/// The `q`-quantile (0..1, nearest rank) of the finite values in `v`; 0 when there are none.
fn quantile(v: &[f32], q: f64) -> f32 {
    let mut s: Vec<f32> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if s.is_empty() {
        return 0.0;
    }
    let k = ((s.len() - 1) as f64 * q).round() as usize;
    let (_, kth, _) = s.select_nth_unstable_by(k, f32::total_cmp);
    *kth
}
