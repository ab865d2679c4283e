//! Contact sheets: one PNG per scene showing what it tests — the surface, a capture, the
//! desired image, what the viewer sees uncompensated, and with the oracle (the scene's ceiling),
//! with closed-loop scores under the panels.

use super::export::full_canvas;
use super::oracle::OracleOptions;
use super::physics::{SetSimulator, Simulator};
use super::score::{ReferenceScores, area_mask, closed_loop};
use crate::error::Result;
use crate::fov;
use crate::playback::place_on_canvas;
use crate::raster::{CamImage, ImageSize, PrjImage, Rect, Rgb, Unspecified};
use crate::resize::resize_area;

/// Frame indices of the sheet's captures (any fixed values; kept apart from the export's).
const FRAME_BLACK: u64 = 1;
const FRAME_WHITE: u64 = 125;
const FRAME_SHEET: u64 = 5_000_000;

/// The displayable area as a real setup finds it: capture black and white on the canvas, FOV
/// mask from them ([`fov::fov_mask`]), the largest canvas-shaped rectangle inside
/// ([`fov::displayable_area`]), in camera pixels; and the reachable range of desired images
/// there ([`fov::display_range`], as `sim export` scales them by default).
pub fn display_target(sim: &Simulator) -> Result<(Rect, fov::DisplayRange)> {
    let ImageSize {
        width: pw,
        height: ph,
    } = sim.projector_size();
    let black = sim.capture(&PrjImage::new(pw, ph), FRAME_BLACK)?;
    let white = sim.capture(&PrjImage::filled(pw, ph, [1.0; 3]), FRAME_WHITE)?;
    let label = format!("virtual rig scene {:?}", sim.scene().name);
    let mask = fov::fov_mask(&black, &white, &label)?;
    let canvas = full_canvas(sim);
    let area = fov::displayable_area(&mask.mask, canvas.width as f64 / canvas.height as f64)?;
    let range = fov::display_range(&black, &white, area, fov::DESIRED_RANGE_QUANTILE)?;
    Ok((area, range))
}

/// A contact sheet for one test image `test` and one sampling image `sample` (both network
/// size, placed on the full-frame canvas), with the reference scores of `test` in `area`.
/// Panels are the camera frame scaled to at most `panel_width` pixels wide.
pub fn contact_sheet(
    sim: &Simulator,
    sample: &PrjImage,
    test: &PrjImage,
    area: Rect,
    range: fov::DisplayRange,
    panel_width: usize,
) -> Result<(Rgb<Unspecified>, ReferenceScores)> {
    let psize = sim.projector_size();
    let cam = sim.camera_size();
    let canvas = full_canvas(sim);
    let desired = fov::place_in_area(&range.apply(test), area, cam)?;
    let unc = place_on_canvas(test, canvas, psize)?;
    let geo = sim.geometry_only(&desired)?;
    let orc = sim.oracle(&desired, &area_mask(sim, area), OracleOptions::default())?;
    let frame = FRAME_SHEET;
    let frames = super::score::Frames::single(frame);
    let scores = ReferenceScores {
        uncompensated: closed_loop(
            sim,
            std::slice::from_ref(&unc),
            std::slice::from_ref(&desired),
            area,
            frames,
        )?,
        geometry_only: closed_loop(
            sim,
            std::slice::from_ref(&geo),
            std::slice::from_ref(&desired),
            area,
            frames,
        )?,
        oracle: closed_loop(
            sim,
            std::slice::from_ref(&orc),
            std::slice::from_ref(&desired),
            area,
            frames,
        )?,
    };
    let sample_cap = sim.capture(&place_on_canvas(sample, canvas, psize)?, frame + 1)?;
    let unc_cap = sim.capture(&unc, frame)?;
    let orc_cap = sim.capture(&orc, frame)?;
    let db = |s: &crate::metrics::Scores| format!("{:.1} db ssim {:.2}", s.psnr, s.ssim);
    let panels: Vec<(CamImage, String, String)> = vec![
        (
            sim.surface_preview().clone(),
            "surface".into(),
            sim.scene().name.clone(),
        ),
        (sample_cap, "a capture".into(), "sampling image".into()),
        (
            desired,
            "desired".into(),
            format!("area {}x{}", area.width, area.height),
        ),
        (unc_cap, "uncompensated".into(), db(&scores.uncompensated)),
        (orc_cap, "oracle".into(), db(&scores.oracle)),
    ];
    Ok((compose(&panels, cam, panel_width), scores))
}

/// The closed-loop figures of a set's sheet, on its test image in the set's displayable area.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SetScores {
    /// The first projector's own ceiling ([`Simulator::oracle`]), the others black.
    pub first_alone: crate::metrics::Scores,
    /// The set's joint ceiling ([`SetSimulator::oracle`]).
    pub joint: crate::metrics::Scores,
    /// The range of camera values the set reaches across its displayable area (all
    /// projectors black, all white), and the first projector's alone there: what stacking
    /// adds is a higher white.
    pub range: fov::DisplayRange,
    pub first_range: fov::DisplayRange,
    /// How visible the seams of the joint ceiling's picture are
    /// ([`crate::metrics::seam_figure`], a band of [`crate::joint::seam::band_px`] along the overlap edges
    /// in the displayable area); `None` where no overlap edge crosses the area.
    pub seam: Option<crate::metrics::SeamFigure>,
}

/// A contact sheet for a set of projectors and one test image `test` (network size): the
/// surface; each projector's white alone and all of them white (where their pictures fall and
/// overlap); the desired image in the displayable area of the set (the largest canvas-shaped
/// rectangle inside the union of their fields of view, found from black and white captures as
/// a calibration finds it); what the camera sees with the first projector's ceiling alone, and
/// with the set's joint ceiling, each scored in closed loop.
pub fn set_sheet(
    set: &SetSimulator,
    test: &PrjImage,
    panel_width: usize,
) -> Result<(Rgb<Unspecified>, SetScores)> {
    let first = &set.projectors()[0];
    let cam = set.camera_size();
    let label = format!("virtual rig scene {:?}", set.scene().name);
    let black = set.capture(&set.uniform(0.0), FRAME_BLACK)?;
    let white = set.capture(&set.uniform(1.0), FRAME_WHITE)?;
    let mask = fov::fov_mask(&black, &white, &label)?;
    let canvas = full_canvas(first);
    let area = fov::displayable_area(&mask.mask, canvas.width as f64 / canvas.height as f64)?;
    let range = fov::display_range(&black, &white, area, fov::DESIRED_RANGE_QUANTILE)?;
    let desired = fov::place_in_area(&range.apply(test), area, cam)?;
    let inside = area_mask(first, area);
    let opts = OracleOptions::default();
    let dark = set.uniform(0.0);
    let mut alone = dark.clone();
    alone[0] = first.oracle(&desired, &inside, opts)?;
    let joint = set.oracle(&desired, &inside, opts)?;
    let frame = FRAME_SHEET;
    let score = |cap: &CamImage| -> Result<crate::metrics::Scores> {
        crate::metrics::score_pairs([(&cap.crop(area)?, &desired.crop(area)?)])
    };
    let alone_cap = set.capture(&alone, frame)?;
    let joint_cap = set.capture(&joint, frame)?;
    let mut first_white = dark.clone();
    first_white[0] = set.uniform(1.0).swap_remove(0);
    let first_range = fov::display_range(
        &black,
        &set.capture(&first_white, FRAME_WHITE)?,
        area,
        fov::DESIRED_RANGE_QUANTILE,
    )?;
    let (band, away) = set.seam_regions(&inside, crate::joint::seam::band_px(cam));
    let seam = crate::metrics::seam_figure(&joint_cap, &desired, band.data(), away.data()).ok();
    let scores = SetScores {
        first_alone: score(&alone_cap)?,
        joint: score(&joint_cap)?,
        range,
        first_range,
        seam,
    };
    let db = |s: &crate::metrics::Scores| format!("{:.1} db ssim {:.2}", s.psnr, s.ssim);
    // The surface as the room light shows it, darkened where no projector of the set reaches.
    let mut surface = first.surface_preview().clone();
    for other in &set.projectors()[1..] {
        for (a, b) in surface
            .data_mut()
            .iter_mut()
            .zip(other.surface_preview().data())
        {
            *a = a.max(*b);
        }
    }
    let mut panels: Vec<(CamImage, String, String)> =
        vec![(surface, "surface".into(), set.scene().name.clone())];
    for k in 0..set.projectors().len() {
        let mut one = dark.clone();
        one[k] = set.uniform(1.0).swap_remove(k);
        let note = if k == 0 {
            format!("others black; up to {:.2}", first_range.high)
        } else {
            "the others black".into()
        };
        panels.push((
            set.capture(&one, FRAME_WHITE + 1 + k as u64)?,
            format!("projector {} white", k + 1),
            note,
        ));
    }
    panels.extend([
        (
            white,
            "all white".into(),
            format!("range {:.2} to {:.2}", range.low, range.high),
        ),
        (
            desired.clone(),
            "desired".into(),
            format!("area {}x{}", area.width, area.height),
        ),
        (
            alone_cap,
            "projector 1 alone".into(),
            db(&scores.first_alone),
        ),
        (
            joint_cap,
            format!(
                "joint oracle{}",
                seam.map_or(String::new(), |s| format!("  seam {:.2}", s.ratio()))
            ),
            db(&scores.joint),
        ),
    ]);
    Ok((compose(&panels, cam, panel_width), scores))
}

/// Lays panels out in a row with two text lines under each.
fn compose(
    panels: &[(CamImage, String, String)],
    cam: ImageSize,
    panel_width: usize,
) -> Rgb<Unspecified> {
    let pw = cam.width.min(panel_width.max(16));
    let ph = ((cam.height * pw) as f64 / cam.width as f64)
        .round()
        .max(1.0) as usize;
    let scale = if pw >= 200 { 2 } else { 1 };
    let line = (GLYPH_H + 3) * scale;
    let gap = 6;
    let width = panels.len() * (pw + gap) + gap;
    let height = gap + ph + 2 * line + gap;
    let mut out = Rgb::<Unspecified>::filled(width, height, [0.12; 3]);
    for (k, (img, top, bottom)) in panels.iter().enumerate() {
        let x0 = gap + k * (pw + gap);
        let small = resize_area(img, pw, ph);
        for y in 0..ph {
            for x in 0..pw {
                out.set(x0 + x, gap + y, small.get(x, y));
            }
        }
        draw_text(
            &mut out,
            x0,
            gap + ph + 2 * scale,
            top,
            scale,
            [0.95; 3],
            pw,
        );
        draw_text(
            &mut out,
            x0,
            gap + ph + 2 * scale + line,
            bottom,
            scale,
            [0.7; 3],
            pw,
        );
    }
    out
}

const GLYPH_W: usize = 5;
const GLYPH_H: usize = 7;

/// Draws lower-case text with a built-in 5×7 font (unknown characters are blank), clipped to
/// `max_width` pixels.
fn draw_text(
    img: &mut Rgb<Unspecified>,
    x0: usize,
    y0: usize,
    text: &str,
    scale: usize,
    colour: [f32; 3],
    max_width: usize,
) {
    let advance = (GLYPH_W + 1) * scale;
    for (i, ch) in text.to_lowercase().chars().enumerate() {
        let gx = x0 + i * advance;
        if gx + GLYPH_W * scale > x0 + max_width {
            break;
        }
        let Some(rows) = glyph(ch) else { continue };
        for (r, bits) in rows.iter().enumerate() {
            for c in 0..GLYPH_W {
                if bits & (1 << (GLYPH_W - 1 - c)) == 0 {
                    continue;
                }
                for dy in 0..scale {
                    for dx in 0..scale {
                        let (x, y) = (gx + c * scale + dx, y0 + r * scale + dy);
                        if x < img.width() && y < img.height() {
                            img.set(x, y, colour);
                        }
                    }
                }
            }
        }
    }
}

fn glyph(ch: char) -> Option<&'static [u8; 7]> {
    FONT.iter().find(|(c, _)| *c == ch).map(|(_, g)| g)
}

/// 5×7 glyphs, one row per entry, most significant of the five bits on the left.
#[rustfmt::skip]
const FONT: &[(char, [u8; 7])] = &[
    ('a', [0b00000, 0b00000, 0b01110, 0b00001, 0b01111, 0b10001, 0b01111]),
    ('b', [0b10000, 0b10000, 0b11110, 0b10001, 0b10001, 0b10001, 0b11110]),
    ('c', [0b00000, 0b00000, 0b01111, 0b10000, 0b10000, 0b10000, 0b01111]),
    ('d', [0b00001, 0b00001, 0b01111, 0b10001, 0b10001, 0b10001, 0b01111]),
    ('e', [0b00000, 0b00000, 0b01110, 0b10001, 0b11111, 0b10000, 0b01110]),
    ('f', [0b00110, 0b01000, 0b11110, 0b01000, 0b01000, 0b01000, 0b01000]),
    ('g', [0b00000, 0b00000, 0b01111, 0b10001, 0b01111, 0b00001, 0b01110]),
    ('h', [0b10000, 0b10000, 0b11110, 0b10001, 0b10001, 0b10001, 0b10001]),
    ('i', [0b00100, 0b00000, 0b01100, 0b00100, 0b00100, 0b00100, 0b01110]),
    ('j', [0b00010, 0b00000, 0b00110, 0b00010, 0b00010, 0b10010, 0b01100]),
    ('k', [0b10000, 0b10000, 0b10010, 0b10100, 0b11000, 0b10100, 0b10010]),
    ('l', [0b01100, 0b00100, 0b00100, 0b00100, 0b00100, 0b00100, 0b01110]),
    ('m', [0b00000, 0b00000, 0b11010, 0b10101, 0b10101, 0b10101, 0b10101]),
    ('n', [0b00000, 0b00000, 0b11110, 0b10001, 0b10001, 0b10001, 0b10001]),
    ('o', [0b00000, 0b00000, 0b01110, 0b10001, 0b10001, 0b10001, 0b01110]),
    ('p', [0b00000, 0b00000, 0b11110, 0b10001, 0b11110, 0b10000, 0b10000]),
    ('q', [0b00000, 0b00000, 0b01111, 0b10001, 0b01111, 0b00001, 0b00001]),
    ('r', [0b00000, 0b00000, 0b10110, 0b11001, 0b10000, 0b10000, 0b10000]),
    ('s', [0b00000, 0b00000, 0b01111, 0b10000, 0b01110, 0b00001, 0b11110]),
    ('t', [0b01000, 0b01000, 0b11110, 0b01000, 0b01000, 0b01001, 0b00110]),
    ('u', [0b00000, 0b00000, 0b10001, 0b10001, 0b10001, 0b10001, 0b01111]),
    ('v', [0b00000, 0b00000, 0b10001, 0b10001, 0b10001, 0b01010, 0b00100]),
    ('w', [0b00000, 0b00000, 0b10001, 0b10001, 0b10101, 0b10101, 0b01010]),
    ('x', [0b00000, 0b00000, 0b10001, 0b01010, 0b00100, 0b01010, 0b10001]),
    ('y', [0b00000, 0b00000, 0b10001, 0b10001, 0b01111, 0b00001, 0b01110]),
    ('z', [0b00000, 0b00000, 0b11111, 0b00010, 0b00100, 0b01000, 0b11111]),
    ('0', [0b01110, 0b10001, 0b10011, 0b10101, 0b11001, 0b10001, 0b01110]),
    ('1', [0b00100, 0b01100, 0b00100, 0b00100, 0b00100, 0b00100, 0b01110]),
    ('2', [0b01110, 0b10001, 0b00001, 0b00010, 0b00100, 0b01000, 0b11111]),
    ('3', [0b11110, 0b00001, 0b00001, 0b01110, 0b00001, 0b00001, 0b11110]),
    ('4', [0b00010, 0b00110, 0b01010, 0b10010, 0b11111, 0b00010, 0b00010]),
    ('5', [0b11111, 0b10000, 0b11110, 0b00001, 0b00001, 0b10001, 0b01110]),
    ('6', [0b00110, 0b01000, 0b10000, 0b11110, 0b10001, 0b10001, 0b01110]),
    ('7', [0b11111, 0b00001, 0b00010, 0b00100, 0b01000, 0b01000, 0b01000]),
    ('8', [0b01110, 0b10001, 0b10001, 0b01110, 0b10001, 0b10001, 0b01110]),
    ('9', [0b01110, 0b10001, 0b10001, 0b01111, 0b00001, 0b00010, 0b01100]),
    ('.', [0b00000, 0b00000, 0b00000, 0b00000, 0b00000, 0b01100, 0b01100]),
    ('-', [0b00000, 0b00000, 0b00000, 0b01110, 0b00000, 0b00000, 0b00000]),
    (':', [0b00000, 0b01100, 0b01100, 0b00000, 0b01100, 0b01100, 0b00000]),
    ('/', [0b00000, 0b00001, 0b00010, 0b00100, 0b01000, 0b10000, 0b00000]),
    ('(', [0b00010, 0b00100, 0b01000, 0b01000, 0b01000, 0b00100, 0b00010]),
    (')', [0b01000, 0b00100, 0b00010, 0b00010, 0b00010, 0b00100, 0b01000]),
    (',', [0b00000, 0b00000, 0b00000, 0b00000, 0b01100, 0b00100, 0b01000]),
];
