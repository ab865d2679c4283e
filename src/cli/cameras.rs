//! `compend cameras [--json] [--device PATH]`: the V4L2 devices (/dev/video*), each with its
//! driver and card name, pixel formats with frame sizes and rates, and controls with range and
//! current value. No camera is not an error (a line saying so, or `[]` in JSON); a `--device`
//! that is not a camera is (exit 2).

use std::path::PathBuf;

use anyhow::Result;
use compend::camera::list::{CameraListing, render};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Print a JSON array of the devices (path, driver, card, bus, capture, formats with sizes
    /// and fps, controls with id, name, kind, min, max, step, default, value, menu) instead of
    /// text.
    #[arg(long)]
    pub json: bool,
    /// Show this device only: a /dev/videoN, a stable /dev/v4l/by-id/... link, or a camera's
    /// index or part of its name.
    #[arg(long, value_name = "PATH")]
    pub device: Option<PathBuf>,
}

#[cfg(target_os = "linux")]
fn read(device: Option<&std::path::Path>) -> compend::Result<Vec<CameraListing>> {
    use compend::camera::v4l2;
    Ok(match device {
        Some(p) => vec![v4l2::describe(&compend::camera::find::resolve(p)?)?],
        None => v4l2::list()?,
    })
}

#[cfg(not(target_os = "linux"))]
fn read(device: Option<&std::path::Path>) -> compend::Result<Vec<CameraListing>> {
    match device {
        Some(p) => Err(compend::Error::Input(format!(
            "{}: cameras are read through V4L2, which only Linux has",
            p.display()
        ))),
        // Found (through nokhwa), but not opened: formats and controls come from V4L2.
        None => Ok(compend::camera::find::find()?
            .into_iter()
            .map(|c| {
                let why = compend::Error::Input(
                    "formats and controls are read through V4L2, which only Linux has".into(),
                );
                let mut l = CameraListing::unreadable(&PathBuf::from(c.index.to_string()), &why);
                l.card = c.name;
                l
            })
            .collect()),
    }
}

pub fn run(args: Args) -> Result<()> {
    let list = read(args.device.as_deref())?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&list)?);
    } else {
        print!("{}", render(&list));
    }
    Ok(())
}
