//! A scripted fake camera for the tests: an [`Opener`] whose devices serve queued frames,
//! timeouts and unplugs, and keep their controls the way uvcvideo does (values clamped, the
//! exposure ignored while automatic and reset by the switch to manual).

use std::cell::RefCell;
use std::collections::{BTreeMap, VecDeque};
use std::io;
use std::path::Path;
use std::rc::Rc;
use std::time::Duration;

use compend::camera::controls::{ControlInfo, ControlKind, MenuEntry, cid};
use compend::camera::format::SizeOffer;
use compend::camera::{
    ActiveFormat, Controls, Device, FormatChoice, FormatOffer, FourCc, Opener, RawFrame,
};
use compend::raster::ImageSize;

/// What the fake device does next when asked for a frame.
pub enum Event {
    Frame {
        data: Vec<u8>,
        seq: u32,
        error: bool,
    },
    /// Nothing within the timeout.
    Timeout,
    /// The device went away (ENODEV).
    Gone,
}

/// Shared between the opener, every device it opened, and the test.
#[derive(Default)]
pub struct Script {
    pub formats: Vec<FormatOffer>,
    /// The driver's colorimetry fields (colorspace, ycbcr_enc, quantization).
    pub colorimetry: (u32, u32, u32),
    /// Opens that fail (device missing) before one succeeds.
    pub failing_opens: u32,
    pub opens: u32,
    pub events: VecDeque<Event>,
    /// Every control write: (open number, id, value).
    pub writes: Vec<(u32, u32, i64)>,
    /// Writing the gain resets the exposure (some cameras do).
    pub gain_resets_exposure: bool,
    /// Control writes refused with EACCES.
    pub refused: Vec<u32>,
}

pub type Shared = Rc<RefCell<Script>>;

pub struct FakeOpener(pub Shared);

pub struct FakeDevice {
    script: Shared,
    open_no: u32,
    controls: BTreeMap<u32, ControlInfo>,
    active: Option<ActiveFormat>,
    buf: Vec<u8>,
}

fn control(id: u32, kind: ControlKind, (min, max): (i64, i64), value: i64) -> ControlInfo {
    ControlInfo {
        id,
        name: format!("control {id:#x}"),
        kind,
        min,
        max,
        step: 1,
        default: min,
        value: Some(value),
        read_only: false,
        inactive: false,
        menu: vec![],
    }
}

/// A webcam's controls as the driver has them after plugging in: everything automatic, no
/// focus controls.
fn webcam_controls() -> BTreeMap<u32, ControlInfo> {
    let mut auto = control(cid::EXPOSURE_AUTO, ControlKind::Menu, (0, 3), 3);
    auto.menu = vec![
        MenuEntry {
            index: 1,
            name: "Manual Mode".into(),
        },
        MenuEntry {
            index: 3,
            name: "Aperture Priority Mode".into(),
        },
    ];
    let mut exposure = control(cid::EXPOSURE_ABSOLUTE, ControlKind::Integer, (3, 2047), 250);
    exposure.default = 156;
    let mut power = control(cid::POWER_LINE_FREQUENCY, ControlKind::Menu, (0, 2), 2);
    power.menu = (0..3)
        .map(|index| MenuEntry {
            index,
            name: format!("{index}"),
        })
        .collect();
    let mut wb = control(
        cid::WHITE_BALANCE_TEMPERATURE,
        ControlKind::Integer,
        (2800, 6500),
        4600,
    );
    wb.step = 10;
    [
        auto,
        control(cid::EXPOSURE_AUTO_PRIORITY, ControlKind::Boolean, (0, 1), 1),
        exposure,
        control(cid::GAIN, ControlKind::Integer, (0, 255), 40),
        control(cid::AUTO_WHITE_BALANCE, ControlKind::Boolean, (0, 1), 1),
        wb,
        control(cid::BACKLIGHT_COMPENSATION, ControlKind::Integer, (0, 1), 1),
        power,
    ]
    .into_iter()
    .map(|c| (c.id, c))
    .collect()
}

impl Opener for FakeOpener {
    type Device = FakeDevice;
    fn open(&mut self, path: &Path) -> compend::Result<FakeDevice> {
        let mut s = self.0.borrow_mut();
        s.opens += 1;
        if s.failing_opens > 0 {
            s.failing_opens -= 1;
            return Err(compend::Error::Missing {
                path: path.to_path_buf(),
                expected: "a V4L2 capture device".into(),
            });
        }
        Ok(FakeDevice {
            script: self.0.clone(),
            open_no: s.opens,
            controls: webcam_controls(),
            active: None,
            buf: Vec::new(),
        })
    }
}

impl Controls for FakeDevice {
    fn controls(&mut self) -> compend::Result<Vec<ControlInfo>> {
        Ok(self.controls.values().cloned().collect())
    }

    fn get_control(&mut self, id: u32) -> io::Result<i64> {
        self.controls
            .get(&id)
            .and_then(|c| c.value)
            .ok_or_else(|| io::Error::from_raw_os_error(libc::EINVAL))
    }

    /// Like uvcvideo: values clamped to the range, menus checked, the exposure ignored while
    /// automatic, the white balance ignored while automatic, and the exposure reset to its
    /// default by the switch to manual.
    fn set_control(&mut self, id: u32, value: i64) -> io::Result<()> {
        let mut s = self.script.borrow_mut();
        s.writes.push((self.open_no, id, value));
        if s.refused.contains(&id) {
            return Err(io::Error::from_raw_os_error(libc::EACCES));
        }
        let auto = |m: &BTreeMap<u32, ControlInfo>, id| m.get(&id).and_then(|c| c.value);
        let ignored = (id == cid::EXPOSURE_ABSOLUTE
            && auto(&self.controls, cid::EXPOSURE_AUTO) != Some(1))
            || (id == cid::WHITE_BALANCE_TEMPERATURE
                && auto(&self.controls, cid::AUTO_WHITE_BALANCE) != Some(0));
        let c = self
            .controls
            .get_mut(&id)
            .ok_or_else(|| io::Error::from_raw_os_error(libc::EINVAL))?;
        if !c.offers(value) {
            return Err(io::Error::from_raw_os_error(libc::EINVAL));
        }
        if ignored {
            return Ok(());
        }
        c.value = Some(c.fit(value));
        let reset =
            (id == cid::EXPOSURE_AUTO && value == 1) || (id == cid::GAIN && s.gain_resets_exposure);
        if reset && let Some(e) = self.controls.get_mut(&cid::EXPOSURE_ABSOLUTE) {
            e.value = Some(e.default);
        }
        Ok(())
    }
}

impl Device for FakeDevice {
    fn formats(&mut self) -> compend::Result<Vec<FormatOffer>> {
        Ok(self.script.borrow().formats.clone())
    }

    fn format(&mut self) -> compend::Result<ActiveFormat> {
        self.active
            .ok_or_else(|| compend::Error::Failed("no format set".into()))
    }

    fn set_format(&mut self, choice: FormatChoice) -> compend::Result<ActiveFormat> {
        let (colorspace, ycbcr_enc, quantization) = self.script.borrow().colorimetry;
        let active = ActiveFormat {
            format: choice.format,
            size: choice.size,
            stride: choice.format.row_bytes(choice.size.width),
            colorspace,
            ycbcr_enc,
            quantization,
        };
        self.active = Some(active);
        Ok(active)
    }

    fn start(&mut self) -> compend::Result<()> {
        Ok(())
    }

    fn next_frame(&mut self, timeout: Duration) -> io::Result<RawFrame<'_>> {
        let event = self.script.borrow_mut().events.pop_front();
        match event {
            Some(Event::Frame { data, seq, error }) => {
                self.buf = data;
                Ok(RawFrame {
                    data: &self.buf,
                    sequence: seq,
                    timestamp: Duration::from_millis(seq as u64 * 33),
                    error,
                })
            }
            Some(Event::Gone) => Err(io::Error::from_raw_os_error(libc::ENODEV)),
            Some(Event::Timeout) | None => {
                std::thread::sleep(timeout.min(Duration::from_millis(20)));
                Err(io::Error::new(io::ErrorKind::TimedOut, "no frame"))
            }
        }
    }
}

pub fn offer(code: &[u8; 4], sizes: &[(usize, usize)]) -> FormatOffer {
    FormatOffer {
        fourcc: FourCc(*code),
        description: String::from_utf8_lossy(code).into_owned(),
        sizes: sizes
            .iter()
            .map(|&(w, h)| SizeOffer {
                size: ImageSize::new(w, h),
                fps: vec![30.0],
                fps_range: false,
            })
            .collect(),
        steps: None,
    }
}

/// A fake webcam: MJPEG at 16x8 and 8x4, YUYV at 8x4 only.
pub fn script() -> Shared {
    Rc::new(RefCell::new(Script {
        formats: vec![
            offer(b"MJPG", &[(16, 8), (8, 4)]),
            offer(b"YUYV", &[(8, 4)]),
        ],
        ..Script::default()
    }))
}
