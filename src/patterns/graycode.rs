//! Gray-code structured light: the patterns a projector shows and the decoder that turns their
//! captures into a dense camera → projector correspondence map.
//!
//! # Pattern sequence
//!
//! For a projector of `W×H` pixels, with `cb = ceil(log2 W)` column bits and `rb = ceil(log2 H)`
//! row bits, the sequence (0-based index `i`; on disk `sl/img_{i+1:04}.png`) is
//!
//! | index | image |
//! |---|---|
//! | 0 | white |
//! | 1 | black |
//! | 2 + 2k, 3 + 2k (k < cb) | column bit k (most significant first) and its inverse |
//! | 2 + 2cb + 2k, 3 + 2cb + 2k (k < rb) | row bit k (most significant first) and its inverse |
//!
//! so `len = 2 + 2·(cb + rb)`; 800×600 gives 10 + 10 bits and 42 images. Projector column `x`
//! carries the reflected binary Gray code `g = x ^ (x >> 1)`; in the pattern of column bit `k` a
//! pixel is white (1.0) where bit `cb − 1 − k` of `g(x)` is 1 and black (0.0) elsewhere; the
//! inverse is the complement. Rows likewise with `g(y)`. Codes are not centred: column 0 has code 0
//! and codes `W..2^cb` are never shown (a decoded code ≥ W is invalid).
//!
//! # Decoding
//!
//! Captures are in camera pixels, RGB in [0,1]; the decoder works on their channel mean. A camera
//! pixel is *lit* where `white − black` exceeds [`DecodeParams::lit_threshold`], a threshold
//! relative to the lit range of the whole capture (its 99th percentile of `white − black`) with an
//! absolute floor. A lit pixel is *valid* when, for every bit, `|pattern − inverse|` exceeds
//! [`DecodeParams::bit_threshold`] at that pixel (relative to its own `white − black`, with an
//! absolute floor), and the decoded column and row lie inside the projector. One exception, on
//! by default ([`DecodeParams::accept_boundary`]): a single undecided bit per axis is accepted
//! when flipping it changes the decoded column (row) by exactly one — the camera pixel straddles
//! the boundary between two neighbouring projector columns, which is what an undecided bit means
//! when the camera is coarser than the projector or slightly out of focus — and the coordinate
//! is then the midpoint of the two (`n + 0.5`). The correspondence
//! gives, per camera pixel, the projector position `(x, y)` it sees, in projector pixel
//! coordinates with pixel centres at integers (`0..W−1`, `0..H−1`; boundary pixels at halves).

use crate::error::{Error, Result};
use crate::raster::{CamImage, Camera, Mask, Plane, PrjImage, Projector, Rgb};

/// Number of bits needed to give every one of `n` positions its own code: `ceil(log2 n)`
/// (0 for n = 1).
pub fn bits_for(n: usize) -> usize {
    if n <= 1 {
        0
    } else {
        (usize::BITS - (n - 1).leading_zeros()) as usize
    }
}

/// Reflected binary Gray code of `v`.
#[inline]
pub fn to_gray(v: u32) -> u32 {
    v ^ (v >> 1)
}

/// Inverse of [`to_gray`].
#[inline]
pub fn from_gray(mut g: u32) -> u32 {
    let mut shift = 1;
    while shift < u32::BITS {
        g ^= g >> shift;
        shift <<= 1;
    }
    g
}

/// What one image of the sequence shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PatternKind {
    White,
    Black,
    /// Column bit `bit` (0 = most significant), `inverted` for the complementary image.
    Column {
        bit: usize,
        inverted: bool,
    },
    /// Row bit `bit` (0 = most significant), `inverted` for the complementary image.
    Row {
        bit: usize,
        inverted: bool,
    },
}

/// The Gray-code pattern set of a `width × height` projector.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GrayCode {
    width: usize,
    height: usize,
    col_bits: usize,
    row_bits: usize,
}

impl GrayCode {
    /// Patterns for a projector of `width × height` pixels (both at least 1, at most 2^31).
    pub fn new(width: usize, height: usize) -> Result<Self> {
        if width == 0 || height == 0 {
            return Err(Error::Input(format!(
                "structured light: projector size {width}x{height} must be at least 1x1"
            )));
        }
        let limit = 1usize << 31;
        if width > limit || height > limit {
            return Err(Error::Input(format!(
                "structured light: projector size {width}x{height} is too large"
            )));
        }
        Ok(Self {
            width,
            height,
            col_bits: bits_for(width),
            row_bits: bits_for(height),
        })
    }

    /// Projector (width, height) in pixels.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }
    /// Number of column bits, `ceil(log2 W)`.
    pub fn col_bits(&self) -> usize {
        self.col_bits
    }
    /// Number of row bits, `ceil(log2 H)`.
    pub fn row_bits(&self) -> usize {
        self.row_bits
    }

    /// Number of images in the sequence: `2 + 2·(col_bits + row_bits)`.
    pub fn len(&self) -> usize {
        2 + 2 * (self.col_bits + self.row_bits)
    }

    /// Never true: the sequence always holds at least white and black.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// What image `index` (0-based) shows, or `None` past the end.
    pub fn kind(&self, index: usize) -> Option<PatternKind> {
        match index {
            0 => Some(PatternKind::White),
            1 => Some(PatternKind::Black),
            i if i < 2 + 2 * self.col_bits => Some(PatternKind::Column {
                bit: (i - 2) / 2,
                inverted: (i - 2) % 2 == 1,
            }),
            i if i < self.len() => {
                let j = i - 2 - 2 * self.col_bits;
                Some(PatternKind::Row {
                    bit: j / 2,
                    inverted: j % 2 == 1,
                })
            }
            _ => None,
        }
    }

    /// Image `index` (0-based) of the sequence at projector resolution: values 0.0 or 1.0.
    pub fn pattern(&self, index: usize) -> Result<PrjImage> {
        let kind = self.kind(index).ok_or_else(|| {
            Error::Input(format!(
                "structured light: pattern index {index} out of range (the {}x{} sequence has {} images)",
                self.width,
                self.height,
                self.len()
            ))
        })?;
        let (w, h) = (self.width, self.height);
        Ok(match kind {
            PatternKind::White => Rgb::filled(w, h, [1.0; 3]),
            PatternKind::Black => Rgb::filled(w, h, [0.0; 3]),
            PatternKind::Column { bit, inverted } => {
                let shift = self.col_bits - 1 - bit;
                let on: Vec<bool> = (0..w)
                    .map(|x| ((to_gray(x as u32) >> shift) & 1 == 1) != inverted)
                    .collect();
                Rgb::from_fn(w, h, |x, _| if on[x] { [1.0; 3] } else { [0.0; 3] })
            }
            PatternKind::Row { bit, inverted } => {
                let shift = self.row_bits - 1 - bit;
                Rgb::from_fn(w, h, |_, y| {
                    if ((to_gray(y as u32) >> shift) & 1 == 1) != inverted {
                        [1.0; 3]
                    } else {
                        [0.0; 3]
                    }
                })
            }
        })
    }

    /// All images of the sequence, in order (generated lazily, one at a time).
    pub fn patterns(&self) -> impl Iterator<Item = PrjImage> + '_ {
        (0..self.len()).map(|i| self.pattern(i).expect("index below len() is in range"))
    }

    /// Decodes the captures of the whole sequence (same order as the patterns, all of one size)
    /// with the default [`DecodeParams`].
    pub fn decode(&self, captures: &[CamImage]) -> Result<Correspondence> {
        self.decode_with(captures, &DecodeParams::default())
    }

    /// Decodes the captures of the whole sequence with explicit thresholds.
    pub fn decode_with(
        &self,
        captures: &[CamImage],
        params: &DecodeParams,
    ) -> Result<Correspondence> {
        if captures.len() != self.len() {
            return Err(Error::Input(format!(
                "structured light: got {} captures, the {}x{} sequence needs {} (white, black, {} column and {} row bit pairs)",
                captures.len(),
                self.width,
                self.height,
                self.len(),
                self.col_bits,
                self.row_bits
            )));
        }
        let first = &captures[0];
        let mut decoder = Decoder::new(*self, first.width(), first.height(), *params);
        for c in captures {
            decoder.push(c)?;
        }
        decoder.finish()
    }
}

/// Thresholds of the decoder. Intensities are channel means of captures in [0,1].
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
    pub projector: (usize, usize),
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
    pub fn size(&self) -> (usize, usize) {
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
        let (pw, ph) = self.projector;
        let mut sx = vec![0f64; pw * ph];
        let mut sy = vec![0f64; pw * ph];
        let mut n = vec![0u32; pw * ph];
        let (cw, ch) = self.size();
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
        if capture.size() != (self.width, self.height) {
            return Err(Error::Shape(format!(
                "structured light capture {} is {}x{}, the first was {}x{}",
                index + 1,
                capture.width(),
                capture.height(),
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
        let (pw, ph) = self.code.size();
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
            projector: (pw, ph),
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bits_and_lengths() {
        assert_eq!(bits_for(1), 0);
        assert_eq!(bits_for(2), 1);
        assert_eq!(bits_for(3), 2);
        assert_eq!(bits_for(4), 2);
        assert_eq!(bits_for(5), 3);
        assert_eq!(bits_for(600), 10);
        assert_eq!(bits_for(800), 10);
        assert_eq!(bits_for(1024), 10);
        assert_eq!(bits_for(1025), 11);
        assert_eq!(GrayCode::new(800, 600).unwrap().len(), 42);
        assert_eq!(GrayCode::new(1, 1).unwrap().len(), 2);
        assert!(GrayCode::new(0, 10).is_err());
    }

    #[test]
    fn gray_round_trip_and_adjacency() {
        for v in 0..5000u32 {
            assert_eq!(from_gray(to_gray(v)), v);
            // Neighbouring codes differ in exactly one bit.
            assert_eq!((to_gray(v) ^ to_gray(v + 1)).count_ones(), 1);
        }
        assert_eq!(from_gray(to_gray(u32::MAX)), u32::MAX);
    }

    #[test]
    fn sequence_order() {
        let g = GrayCode::new(8, 4).unwrap(); // 3 column bits, 2 row bits
        assert_eq!(g.len(), 12);
        assert_eq!(g.kind(0), Some(PatternKind::White));
        assert_eq!(g.kind(1), Some(PatternKind::Black));
        assert_eq!(
            g.kind(2),
            Some(PatternKind::Column {
                bit: 0,
                inverted: false
            })
        );
        assert_eq!(
            g.kind(7),
            Some(PatternKind::Column {
                bit: 2,
                inverted: true
            })
        );
        assert_eq!(
            g.kind(8),
            Some(PatternKind::Row {
                bit: 0,
                inverted: false
            })
        );
        assert_eq!(
            g.kind(11),
            Some(PatternKind::Row {
                bit: 1,
                inverted: true
            })
        );
        assert_eq!(g.kind(12), None);
        assert!(g.pattern(12).is_err());
        // MSB column pattern of an 8-wide projector: Gray codes 0,1,3,2,6,7,5,4 → MSB 0,0,0,0,1,1,1,1.
        let p = g.pattern(2).unwrap();
        let row: Vec<f32> = (0..8).map(|x| p.get(x, 3)[0]).collect();
        assert_eq!(row, vec![0., 0., 0., 0., 1., 1., 1., 1.]);
        // LSB: bits 0,1,1,0,0,1,1,0 and the inverse is the complement.
        let p = g.pattern(6).unwrap();
        let q = g.pattern(7).unwrap();
        let row: Vec<f32> = (0..8).map(|x| p.get(x, 0)[1]).collect();
        assert_eq!(row, vec![0., 1., 1., 0., 0., 1., 1., 0.]);
        for (a, b) in p.data().iter().zip(q.data()) {
            assert_eq!(a + b, 1.0);
        }
    }
}
