//! `compend show`: a projector-space PNG on the projector window, as is (e.g. to check which
//! monitor is the projector, or a structured-light pattern).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Result;
use compend::device::DisplaySink;
use compend::raster::{ImageSize, PrjImage, Rect};
use compend::window::ProjectorWindow;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The PNG to show; stretched over the whole projector frame when its size differs.
    pub image: PathBuf,
    /// The projector's monitor: its name or index [default: the primary monitor].
    #[arg(long)]
    pub monitor: Option<String>,
    /// Close after this many seconds [default: when the window is closed or Escape is pressed].
    #[arg(long)]
    pub seconds: Option<f64>,
}

pub fn run(args: Args) -> Result<()> {
    let img: PrjImage = compend::pngio::read_rgb(&args.image)?;
    let mut win = ProjectorWindow::open(args.monitor.as_deref())?;
    let ImageSize {
        width: w,
        height: h,
    } = DisplaySink::size(&win);
    let frame = if img.size() == ImageSize::new(w, h) {
        img
    } else {
        let full = Rect {
            x: 0,
            y: 0,
            width: w,
            height: h,
        };
        compend::playback::place_on_canvas(&img, full, ImageSize::new(w, h))?
    };
    win.show(&frame)?;
    eprintln!(
        "show: presented {} on the projector window {w}x{h} ({})",
        args.image.display(),
        win.context().describe()
    );
    let start = Instant::now();
    while win.pump()
        && args
            .seconds
            .is_none_or(|s| start.elapsed().as_secs_f64() < s)
    {
        win.show(&frame)?;
        std::thread::sleep(Duration::from_millis(15));
    }
    Ok(())
}
