//! The benchmark's charts: closed-loop accuracy against training time and
//! against per-frame time, one point per benchmark row and one colour per method.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use plotters::prelude::*;

use super::row::Row;

/// One chart: x from each row (seconds or milliseconds, drawn on a log axis), y = the gap to the
/// oracle in dB (lower is better).
struct Spec {
    file: &'static str,
    title: &'static str,
    x_label: &'static str,
    x: fn(&Row) -> Option<f64>,
}

const SPECS: [Spec; 2] = [
    Spec {
        file: "accuracy-vs-training.png",
        title: "closed-loop gap to the oracle vs training time",
        x_label: "training time (s, log scale)",
        x: |r| r.train_seconds,
    },
    Spec {
        file: "accuracy-vs-frame.png",
        title: "closed-loop gap to the oracle vs time per frame (CPU reference)",
        x_label: "time per frame (ms, log scale)",
        x: |r| r.frame_ms_cpu,
    },
];

/// The charts' font, built in (assets/fonts/LICENSE-DejaVu.txt), so that drawing needs no font
/// from the system: compend links no font library.
const FONT: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSans.ttf");

/// The font family the charts name.
const FAMILY: &str = "sans-serif";

/// Writes the charts into `dir`; returns their paths. Rows without the needed numbers (reference
/// rows, failed runs) are left out; a chart with no point is not written.
pub fn write_charts(rows: &[Row], dir: &Path) -> Result<Vec<PathBuf>> {
    plotters::style::register_font(FAMILY, FontStyle::Normal, FONT)
        .map_err(|_| anyhow::anyhow!("the built-in chart font is not a font file"))?;
    let mut methods: Vec<&str> = Vec::new();
    for r in rows {
        if !methods.contains(&r.method.as_str()) {
            methods.push(&r.method);
        }
    }
    let mut written = Vec::new();
    for spec in &SPECS {
        let points: Vec<(usize, f64, f64)> = rows
            .iter()
            .filter_map(|r| {
                let x = (spec.x)(r).filter(|v| v.is_finite() && *v > 0.0)?;
                let y = r.gap_db.filter(|v| v.is_finite())?;
                let m = methods.iter().position(|m| *m == r.method)?;
                Some((m, x, y))
            })
            .collect();
        if points.is_empty() {
            continue;
        }
        let path = dir.join(spec.file);
        draw(spec, &points, &methods, &path)
            .with_context(|| format!("drawing {}", path.display()))?;
        written.push(path);
    }
    Ok(written)
}

fn draw(spec: &Spec, points: &[(usize, f64, f64)], methods: &[&str], path: &Path) -> Result<()> {
    let (x0, x1) = bounds(points.iter().map(|p| p.1));
    let (_, y1) = bounds(points.iter().map(|p| p.2));
    // The axis starts at a power of ten: plotters labels a log axis from the first power of ten
    // inside it, so points below that would sit left of every label.
    let (x0, x1) = (10f64.powf((x0 / 1.5).log10().floor()), x1 * 1.5);
    let y1 = (y1 * 1.1).max(1.0);
    const SIZE: (u32, u32) = (900, 600);
    // Drawn in memory (RGB, 8 bits) and written atomically like every other file.
    let mut pixels = vec![0u8; SIZE.0 as usize * SIZE.1 as usize * 3];
    draw_into(spec, points, methods, &mut pixels, SIZE, (x0, x1), y1)?;
    let img = compend::raster::Rgb::<compend::raster::Unspecified>::from_vec(
        SIZE.0 as usize,
        SIZE.1 as usize,
        pixels.iter().map(|&v| f32::from(v) / 255.0).collect(),
    )?;
    compend::pngio::write_rgb(path, &img)?;
    Ok(())
}

/// A tick label of the logarithmic axis (seconds or milliseconds): as many decimals as a value
/// of its size needs, so that "20" is not "20.0" and 0.25 is not "0".
fn axis_number(v: f64) -> String {
    if v >= 10.0 {
        format!("{v:.0}")
    } else if v >= 1.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.2}")
    }
}

fn draw_into(
    spec: &Spec,
    points: &[(usize, f64, f64)],
    methods: &[&str],
    pixels: &mut [u8],
    size: (u32, u32),
    (x0, x1): (f64, f64),
    y1: f64,
) -> Result<()> {
    let root = BitMapBackend::with_buffer(pixels, size).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(spec.title, (FAMILY, 20))
        .margin(12)
        .x_label_area_size(44)
        .y_label_area_size(56)
        .build_cartesian_2d((x0..x1).log_scale(), 0.0..y1)?;
    chart
        .configure_mesh()
        .x_label_formatter(&|v| axis_number(*v))
        .x_desc(spec.x_label)
        .y_desc("gap to the oracle (dB, lower is better)")
        .draw()?;
    for (m, name) in methods.iter().enumerate() {
        let colour = Palette99::pick(m).to_rgba();
        let pts: Vec<(f64, f64)> = points
            .iter()
            .filter(|p| p.0 == m)
            .map(|p| (p.1, p.2))
            .collect();
        if pts.is_empty() {
            continue;
        }
        chart
            .draw_series(pts.iter().map(|&p| Circle::new(p, 5, colour.filled())))?
            .label(*name)
            .legend(move |(x, y)| Circle::new((x + 8, y), 5, colour.filled()));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    Ok(())
}

fn bounds(v: impl Iterator<Item = f64>) -> (f64, f64) {
    v.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
        (lo.min(x), hi.max(x))
    })
}
