//! V4L2 capture devices (Linux): a UVC webcam, a capture card. [`V4l2`] opens them as
//! [`Device`]s for a [`Camera`] ([`V4l2Camera`]), and [`describe`] / [`list`] read what
//! `compend cameras` prints.
//!
//! Everything goes through the `v4l` crate's ioctl bindings: capabilities, formats with sizes
//! and frame intervals, the format with its colorimetry fields (which `v4l`'s own `Format`
//! leaves out: `ycbcr_enc`), controls by ID with `VIDIOC_QUERY_EXT_CTRL`, `VIDIOC_G_CTRL` and
//! `VIDIOC_S_CTRL`, and memory-mapped buffers ([`super::ring`]). Names are read leniently (a card
//! name cut inside a UTF-8 character is kept, not a panic).

use std::fs::File;
use std::io;
use std::os::fd::{AsRawFd, RawFd};
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::{Path, PathBuf};
use std::time::Duration;

use v4l::v4l_sys::*;
use v4l::v4l2::vidioc;

use super::capture::{Camera, OpenOptions};
use super::controls::{ControlInfo, ControlKind, Controls, MenuEntry};
use super::format::{ActiveFormat, FormatChoice, FormatOffer, SizeOffer, SizeSteps};
use super::list::CameraListing;
use super::pixels::{FourCc, PixelFormat};
use super::ring::{Ring, xioctl, zeroed};
use super::{Device, Opener, RawFrame};
use crate::error::{Error, Result};
use crate::raster::ImageSize;

/// Buffers the driver fills in turn.
const BUFFERS: u32 = 4;

/// Opens V4L2 devices by path.
#[derive(Clone, Copy, Debug, Default)]
pub struct V4l2;

impl Opener for V4l2 {
    type Device = V4l2Device;
    fn open(&mut self, path: &Path) -> Result<V4l2Device> {
        V4l2Device::open(path)
    }
}

/// A V4L2 camera: [`Camera`] over [`V4l2`].
pub type V4l2Camera = Camera<V4l2>;

impl Camera<V4l2> {
    /// How long a grab waits for a frame unless told otherwise.
    pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(5);

    /// Opens the V4L2 device `camera` names (a device path, or a camera's index or name as
    /// [`super::find::resolve`] reads them) in the format [`super::format::choose_format`] picks
    /// for `size` ((width, height), camera pixels; `None`: the device's current size), and
    /// starts streaming.
    pub fn open(camera: &Path, size: Option<ImageSize>) -> Result<Self> {
        let path = super::find::resolve(camera)?;
        let options = OpenOptions {
            size,
            timeout: Self::DEFAULT_TIMEOUT,
            ..OpenOptions::default()
        };
        Camera::open_with(V4l2, &path, options)
    }
}

/// What `VIDIOC_QUERYCAP` says about a device node.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Caps {
    pub driver: String,
    pub card: String,
    pub bus: String,
    /// Single-planar video capture.
    pub capture: bool,
    /// Multi-planar video capture only (not read by compend).
    pub mplane: bool,
    /// Streaming I/O (memory-mapped buffers).
    pub streaming: bool,
}

/// A NUL-terminated fixed-size C string, read leniently.
fn c_text(bytes: &[u8]) -> String {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    String::from_utf8_lossy(&bytes[..end]).trim().to_string()
}

fn querycap(fd: RawFd) -> io::Result<Caps> {
    let mut c: v4l2_capability = zeroed();
    xioctl(fd, vidioc::VIDIOC_QUERYCAP, &mut c)?;
    let caps = if c.capabilities & V4L2_CAP_DEVICE_CAPS != 0 {
        c.device_caps
    } else {
        c.capabilities
    };
    Ok(Caps {
        driver: c_text(&c.driver),
        card: c_text(&c.card),
        bus: c_text(&c.bus_info),
        capture: caps & V4L2_CAP_VIDEO_CAPTURE != 0,
        mplane: caps & V4L2_CAP_VIDEO_CAPTURE_MPLANE != 0,
        streaming: caps & V4L2_CAP_STREAMING != 0,
    })
}

/// Opens a device node read-write (non-blocking: grabs wait in `poll`, with a timeout) and
/// reads its capabilities. A path that is missing, not a character device, or a character
/// device that is not V4L2 is an input error naming it.
pub fn open_node(path: &Path) -> Result<(File, Caps)> {
    let meta = std::fs::metadata(path).map_err(|e| match e.kind() {
        io::ErrorKind::NotFound => Error::Missing {
            path: path.to_path_buf(),
            expected: "no such camera; `compend cameras` lists the ones there are".into(),
        },
        _ => Error::io(path, "open the camera", e),
    })?;
    if !meta.file_type().is_char_device() {
        let kind = if meta.is_dir() { "a folder" } else { "a file" };
        return Err(Error::Input(format!(
            "{}: not a camera ({kind}, not a V4L2 device node); pass a /dev/videoN that \
             `compend cameras` lists",
            path.display()
        )));
    }
    let file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)
        .map_err(|e| {
            let op = if e.kind() == io::ErrorKind::PermissionDenied {
                "open the camera (is the user in the `video` group?)"
            } else {
                "open the camera"
            };
            Error::io(path, op, e)
        })?;
    let caps = querycap(file.as_raw_fd()).map_err(|e| match e.raw_os_error() {
        Some(libc::ENOTTY | libc::EINVAL) => Error::Input(format!(
            "{}: not a camera (a device that does not speak V4L2); pass a /dev/videoN that \
             `compend cameras` lists",
            path.display()
        )),
        _ => Error::io(path, "query the camera", e),
    })?;
    Ok((file, caps))
}

/// An open V4L2 capture device.
pub struct V4l2Device {
    /// Dropped before `file`: the buffers are released while the descriptor is open.
    ring: Option<Ring>,
    file: File,
    path: PathBuf,
}

impl V4l2Device {
    /// Opens `path`, which must be a single-planar capture device with streaming I/O.
    pub fn open(path: &Path) -> Result<Self> {
        let (file, caps) = open_node(path)?;
        let problem = if caps.capture && !caps.streaming {
            Some("cannot stream (no memory-mapped buffers)")
        } else if !caps.capture && caps.mplane {
            Some("captures multi-planar frames only, which compend does not read")
        } else if !caps.capture {
            Some("is not a video capture node (a UVC camera's second node carries metadata)")
        } else {
            None
        };
        if let Some(p) = problem {
            return Err(Error::Input(format!(
                "{}: \"{}\" ({}) {p}; pick another /dev/videoN from `compend cameras`",
                path.display(),
                caps.card,
                caps.driver
            )));
        }
        Ok(Self {
            ring: None,
            file,
            path: path.to_path_buf(),
        })
    }

    fn fd(&self) -> RawFd {
        self.file.as_raw_fd()
    }

    fn busy_or(&self, op: &'static str, e: io::Error) -> Error {
        if e.raw_os_error() == Some(libc::EBUSY) {
            Error::Failed(format!(
                "{}: busy: another program is using the camera (close it; `fuser {}` names it)",
                self.path.display(),
                self.path.display()
            ))
        } else {
            Error::io(&self.path, op, e)
        }
    }
}

/// Frame rates in frames per second for one size: a list, fastest first, or a range.
fn frame_rates(fd: RawFd, code: u32, size: ImageSize) -> (Vec<f64>, bool) {
    let fps = |f: v4l2_fract| {
        if f.numerator == 0 {
            0.0
        } else {
            f.denominator as f64 / f.numerator as f64
        }
    };
    let mut out = Vec::new();
    for index in 0..64 {
        let mut e: v4l2_frmivalenum = zeroed();
        e.index = index;
        e.pixel_format = code;
        e.width = size.width as u32;
        e.height = size.height as u32;
        if xioctl(fd, vidioc::VIDIOC_ENUM_FRAMEINTERVALS, &mut e).is_err() {
            break;
        }
        // SAFETY: the union member read is the one `type_` names.
        unsafe {
            if e.type_ == v4l2_frmivaltypes_V4L2_FRMIVAL_TYPE_DISCRETE {
                out.push(fps(e.__bindgen_anon_1.discrete));
            } else {
                let s = e.__bindgen_anon_1.stepwise;
                return (vec![fps(s.max), fps(s.min)], true);
            }
        }
    }
    out.sort_by(|a, b| b.total_cmp(a));
    (out, false)
}

/// The frame sizes of one pixel format.
fn frame_sizes(fd: RawFd, code: u32) -> (Vec<SizeOffer>, Option<SizeSteps>) {
    let mut sizes = Vec::new();
    for index in 0..256 {
        let mut e: v4l2_frmsizeenum = zeroed();
        e.index = index;
        e.pixel_format = code;
        if xioctl(fd, vidioc::VIDIOC_ENUM_FRAMESIZES, &mut e).is_err() {
            break;
        }
        // SAFETY: the union member read is the one `type_` names.
        unsafe {
            if e.type_ == v4l2_frmsizetypes_V4L2_FRMSIZE_TYPE_DISCRETE {
                let d = e.__bindgen_anon_1.discrete;
                let size = ImageSize::new(d.width as usize, d.height as usize);
                let (fps, fps_range) = frame_rates(fd, code, size);
                sizes.push(SizeOffer {
                    size,
                    fps,
                    fps_range,
                });
            } else {
                let s = e.__bindgen_anon_1.stepwise;
                let steps = SizeSteps {
                    min: ImageSize::new(s.min_width as usize, s.min_height as usize),
                    max: ImageSize::new(s.max_width as usize, s.max_height as usize),
                    step: ImageSize::new(s.step_width as usize, s.step_height as usize),
                };
                return (sizes, Some(steps));
            }
        }
    }
    (sizes, None)
}

/// Every capture format of the device, with sizes and rates.
fn formats(fd: RawFd) -> io::Result<Vec<FormatOffer>> {
    let mut out = Vec::new();
    for index in 0..64 {
        let mut d: v4l2_fmtdesc = zeroed();
        d.index = index;
        d.type_ = v4l2_buf_type_V4L2_BUF_TYPE_VIDEO_CAPTURE;
        match xioctl(fd, vidioc::VIDIOC_ENUM_FMT, &mut d) {
            Ok(()) => {}
            Err(e) if e.raw_os_error() == Some(libc::EINVAL) => break,
            Err(e) => return Err(e),
        }
        let (sizes, steps) = frame_sizes(fd, d.pixelformat);
        out.push(FormatOffer {
            fourcc: FourCc::from_u32(d.pixelformat),
            description: c_text(&d.description),
            sizes,
            steps,
        });
    }
    Ok(out)
}

/// The device's format as the driver reports it.
fn active(pix: &v4l2_pix_format, path: &Path) -> Result<ActiveFormat> {
    let fourcc = FourCc::from_u32(pix.pixelformat);
    let format = PixelFormat::from_fourcc(fourcc).ok_or_else(|| {
        Error::Failed(format!(
            "{}: the device is set to {fourcc}, which compend does not read",
            path.display()
        ))
    })?;
    Ok(ActiveFormat {
        format,
        size: ImageSize::new(pix.width as usize, pix.height as usize),
        stride: pix.bytesperline as usize,
        colorspace: pix.colorspace,
        // SAFETY: `ycbcr_enc` and `hsv_enc` share the field; both are a u32.
        ycbcr_enc: unsafe { pix.__bindgen_anon_1.ycbcr_enc },
        quantization: pix.quantization,
    })
}

fn get_format(fd: RawFd) -> io::Result<v4l2_format> {
    let mut f: v4l2_format = zeroed();
    f.type_ = v4l2_buf_type_V4L2_BUF_TYPE_VIDEO_CAPTURE;
    xioctl(fd, vidioc::VIDIOC_G_FMT, &mut f)?;
    Ok(f)
}

/// One menu control's entries (at most 64, skipping the indices the driver refuses).
fn menu(fd: RawFd, q: &v4l2_query_ext_ctrl, kind: ControlKind) -> Vec<MenuEntry> {
    let (lo, hi) = (q.minimum.max(0), q.maximum.min(q.minimum.max(0) + 63));
    let mut out = Vec::new();
    for index in lo..=hi {
        let mut m: v4l2_querymenu = zeroed();
        m.id = q.id;
        m.index = index as u32;
        if xioctl(fd, vidioc::VIDIOC_QUERYMENU, &mut m).is_err() {
            continue;
        }
        // The struct is packed: fields are copied out before use. SAFETY: the union member
        // read is the one the control type names.
        let name = if kind == ControlKind::IntegerMenu {
            let value = unsafe { m.__bindgen_anon_1.value };
            value.to_string()
        } else {
            let bytes = unsafe { m.__bindgen_anon_1.name };
            c_text(&bytes)
        };
        out.push(MenuEntry { index, name });
    }
    out
}

/// Every control of the device (classes and disabled controls left out), with values.
fn query_controls(fd: RawFd) -> io::Result<Vec<ControlInfo>> {
    let mut out = Vec::new();
    let mut q: v4l2_query_ext_ctrl = zeroed();
    q.id = V4L2_CTRL_FLAG_NEXT_CTRL;
    loop {
        match xioctl(fd, vidioc::VIDIOC_QUERY_EXT_CTRL, &mut q) {
            Ok(()) => {}
            Err(e) if e.raw_os_error() == Some(libc::EINVAL) => break,
            Err(e) => return Err(e),
        }
        let kind = ControlKind::from_v4l2(q.type_);
        if kind != ControlKind::Class && q.flags & V4L2_CTRL_FLAG_DISABLED == 0 {
            let readable = kind.has_value() && q.flags & V4L2_CTRL_FLAG_WRITE_ONLY == 0;
            let name_bytes: Vec<u8> = q.name.iter().map(|&c| c as u8).collect();
            out.push(ControlInfo {
                id: q.id,
                name: c_text(&name_bytes),
                kind,
                min: q.minimum,
                max: q.maximum,
                step: q.step,
                default: q.default_value,
                value: readable.then(|| get_ctrl(fd, q.id).ok()).flatten(),
                read_only: q.flags & V4L2_CTRL_FLAG_READ_ONLY != 0,
                inactive: q.flags & V4L2_CTRL_FLAG_INACTIVE != 0,
                menu: match kind {
                    ControlKind::Menu | ControlKind::IntegerMenu => menu(fd, &q, kind),
                    _ => Vec::new(),
                },
            });
        }
        q.id |= V4L2_CTRL_FLAG_NEXT_CTRL;
    }
    Ok(out)
}

fn get_ctrl(fd: RawFd, id: u32) -> io::Result<i64> {
    let mut c: v4l2_control = zeroed();
    c.id = id;
    xioctl(fd, vidioc::VIDIOC_G_CTRL, &mut c)?;
    Ok(c.value as i64)
}

impl Controls for V4l2Device {
    fn controls(&mut self) -> Result<Vec<ControlInfo>> {
        query_controls(self.fd()).map_err(|e| Error::io(&self.path, "list the controls", e))
    }

    fn get_control(&mut self, id: u32) -> io::Result<i64> {
        get_ctrl(self.fd(), id)
    }

    fn set_control(&mut self, id: u32, value: i64) -> io::Result<()> {
        let mut c: v4l2_control = zeroed();
        c.id = id;
        c.value = value.clamp(i32::MIN as i64, i32::MAX as i64) as i32;
        xioctl(self.fd(), vidioc::VIDIOC_S_CTRL, &mut c)
    }
}

impl Device for V4l2Device {
    fn formats(&mut self) -> Result<Vec<FormatOffer>> {
        formats(self.fd()).map_err(|e| Error::io(&self.path, "list the formats", e))
    }

    fn format(&mut self) -> Result<ActiveFormat> {
        let f = get_format(self.fd()).map_err(|e| Error::io(&self.path, "read the format", e))?;
        // SAFETY: a capture format's union holds `pix`.
        active(unsafe { &f.fmt.pix }, &self.path)
    }

    fn set_format(&mut self, choice: FormatChoice) -> Result<ActiveFormat> {
        self.ring = None;
        let mut f =
            get_format(self.fd()).map_err(|e| Error::io(&self.path, "read the format", e))?;
        // A capture format's union holds `pix` (writing union fields needs no `unsafe`).
        f.fmt.pix.pixelformat = choice.format.fourcc().to_u32();
        f.fmt.pix.width = choice.size.width as u32;
        f.fmt.pix.height = choice.size.height as u32;
        f.fmt.pix.bytesperline = 0;
        f.fmt.pix.sizeimage = 0;
        xioctl(self.fd(), vidioc::VIDIOC_S_FMT, &mut f)
            .map_err(|e| self.busy_or("set the format", e))?;
        // SAFETY: as above.
        active(unsafe { &f.fmt.pix }, &self.path)
    }

    fn start(&mut self) -> Result<()> {
        if self.ring.is_none() {
            let ring =
                Ring::start(self.fd(), BUFFERS).map_err(|e| self.busy_or("start streaming", e))?;
            self.ring = Some(ring);
        }
        Ok(())
    }

    fn next_frame(&mut self, timeout: Duration) -> io::Result<RawFrame<'_>> {
        match self.ring.as_mut() {
            Some(ring) => ring.next(timeout),
            None => Err(io::Error::new(
                io::ErrorKind::NotConnected,
                "the camera is not streaming",
            )),
        }
    }
}

/// Everything `compend cameras` shows about one device node. A path that is not a V4L2 device
/// is an input error; a V4L2 node that cannot be read further (busy, no capture) is listed
/// with what is known and the reason.
pub fn describe(path: &Path) -> Result<CameraListing> {
    let (file, caps) = open_node(path)?;
    let fd = file.as_raw_fd();
    let mut l = CameraListing {
        path: path.to_path_buf(),
        driver: caps.driver.clone(),
        card: caps.card.clone(),
        bus: caps.bus.clone(),
        capture: caps.capture,
        formats: Vec::new(),
        controls: Vec::new(),
        error: None,
    };
    if !caps.capture {
        return Ok(l);
    }
    let mut problems = Vec::new();
    match formats(fd) {
        Ok(f) => l.formats = f,
        Err(e) => problems.push(format!("formats: {e}")),
    }
    match query_controls(fd) {
        Ok(c) => l.controls = c,
        Err(e) => problems.push(format!("controls: {e}")),
    }
    if !problems.is_empty() {
        l.error = Some(problems.join("; "));
    }
    Ok(l)
}

/// Every camera [`super::find::find`] finds (`/dev/videoN`, in number order), described at its
/// device node. Nodes that cannot be opened are listed with the reason.
pub fn list() -> Result<Vec<CameraListing>> {
    Ok(super::find::find()?
        .into_iter()
        .filter_map(|c| c.path)
        .map(|p| describe(&p).unwrap_or_else(|e| CameraListing::unreadable(&p, &e)))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::controls::cid;

    #[test]
    fn control_ids_match_the_kernel_headers() {
        assert_eq!(cid::EXPOSURE_AUTO, V4L2_CID_EXPOSURE_AUTO);
        assert_eq!(cid::EXPOSURE_ABSOLUTE, V4L2_CID_EXPOSURE_ABSOLUTE);
        assert_eq!(cid::EXPOSURE_AUTO_PRIORITY, V4L2_CID_EXPOSURE_AUTO_PRIORITY);
        assert_eq!(cid::GAIN, V4L2_CID_GAIN);
        assert_eq!(cid::AUTO_WHITE_BALANCE, V4L2_CID_AUTO_WHITE_BALANCE);
        assert_eq!(
            cid::WHITE_BALANCE_TEMPERATURE,
            V4L2_CID_WHITE_BALANCE_TEMPERATURE
        );
        assert_eq!(cid::FOCUS_AUTO, V4L2_CID_FOCUS_AUTO);
        assert_eq!(cid::FOCUS_ABSOLUTE, V4L2_CID_FOCUS_ABSOLUTE);
        assert_eq!(cid::BACKLIGHT_COMPENSATION, V4L2_CID_BACKLIGHT_COMPENSATION);
        assert_eq!(cid::POWER_LINE_FREQUENCY, V4L2_CID_POWER_LINE_FREQUENCY);
    }

    #[test]
    fn names_are_read_leniently() {
        assert_eq!(c_text(b"uvcvideo\0\0\0"), "uvcvideo");
        // A card name cut inside a two-byte UTF-8 character.
        assert_eq!(c_text(&[b'C', b'a', b'm', 0xC3]), "Cam\u{FFFD}");
        assert_eq!(c_text(b"no terminator"), "no terminator");
    }

    #[test]
    fn paths_that_are_not_cameras_are_input_errors() {
        let missing = V4l2Device::open(Path::new("/dev/no-such-video-device")).err();
        assert_eq!(missing.map(|e| e.exit_code()), Some(2));
        let file = V4l2Device::open(Path::new("/etc/passwd")).err().unwrap();
        assert_eq!(file.exit_code(), 2, "{file}");
        assert!(file.to_string().contains("/etc/passwd"), "{file}");
        let dir = V4l2Device::open(Path::new("/tmp")).err().unwrap();
        assert!(dir.to_string().contains("a folder"), "{dir}");
        // A character device that is not V4L2.
        let null = V4l2Device::open(Path::new("/dev/null")).err().unwrap();
        assert_eq!(null.exit_code(), 2, "{null}");
        assert!(null.to_string().contains("V4L2"), "{null}");
    }

    /// By hand, with a UVC camera at /dev/video0: `cargo test --lib camera::v4l2 -- --ignored`.
    /// Two grabs in a row come with increasing sequence numbers and timestamps, and the lock
    /// reports exposure as manual.
    #[test]
    #[ignore = "needs a V4L2 camera"]
    fn grabs_frames_and_locks_controls_on_dev_video0() {
        use crate::device::FrameSource;
        let mut cam = V4l2Camera::open(Path::new("/dev/video0"), None).unwrap();
        let a = cam.grab().unwrap();
        let b = cam.grab().unwrap();
        assert_eq!(a.image.size(), FrameSource::size(&cam));
        assert!(b.seq > a.seq, "sequence {} then {}", a.seq, b.seq);
        assert!(b.timestamp >= a.timestamp);
        let report = cam
            .lock_for_calibration(&crate::camera::LockSettings::default())
            .unwrap();
        println!("{}", report.lines().join("\n"));
        assert!(report.exposure_is_manual());
    }
}
