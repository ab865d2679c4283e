//! Camera controls, matched by V4L2 control ID (their names changed across kernels and
//! drivers: "Exposure, Auto" became "Auto Exposure", "Focus, Auto" became "Focus, Automatic
//! Continuous"), and the lock before calibration ([`lock`]): automatic exposure, white balance
//! and focus off, fixed values written, then read back and reported ([`LockReport`]).
//!
//! Units are the V4L2 ones: exposure in 100 µs, white balance in kelvin, gain and focus in the
//! device's own steps, power-line frequency as a menu (0 off, 1 50 Hz, 2 60 Hz, 3 auto).

use std::io;

use serde::{Deserialize, Serialize};

use crate::error::Result;

/// V4L2 control IDs (`linux/v4l2-controls.h`).
pub mod cid {
    pub const AUTO_WHITE_BALANCE: u32 = 0x0098_090c;
    pub const GAIN: u32 = 0x0098_0913;
    pub const POWER_LINE_FREQUENCY: u32 = 0x0098_0918;
    pub const WHITE_BALANCE_TEMPERATURE: u32 = 0x0098_091a;
    pub const BACKLIGHT_COMPENSATION: u32 = 0x0098_091c;
    /// Menu: 0 auto, 1 manual, 2 shutter priority, 3 aperture priority.
    pub const EXPOSURE_AUTO: u32 = 0x009a_0901;
    /// Exposure time in 100 µs units.
    pub const EXPOSURE_ABSOLUTE: u32 = 0x009a_0902;
    /// Boolean: whether automatic exposure may lower the frame rate.
    pub const EXPOSURE_AUTO_PRIORITY: u32 = 0x009a_0903;
    pub const FOCUS_ABSOLUTE: u32 = 0x009a_090a;
    pub const FOCUS_AUTO: u32 = 0x009a_090c;
}

/// `V4L2_EXPOSURE_MANUAL` and `V4L2_EXPOSURE_SHUTTER_PRIORITY` (manual time, automatic iris).
const EXPOSURE_MANUAL: i64 = 1;
const EXPOSURE_SHUTTER_PRIORITY: i64 = 2;

/// The type of a control (`enum v4l2_ctrl_type`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ControlKind {
    Integer,
    Boolean,
    Menu,
    IntegerMenu,
    Button,
    Integer64,
    Class,
    String,
    Bitmask,
    /// Compound and newer types compend does not read.
    Other(u32),
}

impl ControlKind {
    pub fn from_v4l2(code: u32) -> Self {
        match code {
            1 => Self::Integer,
            2 => Self::Boolean,
            3 => Self::Menu,
            4 => Self::Button,
            5 => Self::Integer64,
            6 => Self::Class,
            7 => Self::String,
            8 => Self::Bitmask,
            9 => Self::IntegerMenu,
            other => Self::Other(other),
        }
    }

    /// Whether the value is one integer that `VIDIOC_G_CTRL` reads.
    pub fn has_value(self) -> bool {
        matches!(
            self,
            Self::Integer | Self::Boolean | Self::Menu | Self::IntegerMenu | Self::Bitmask
        )
    }
}

/// One entry of a menu control.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MenuEntry {
    pub index: i64,
    /// The entry's name, or its number for integer menus.
    pub name: String,
}

/// A control as the driver describes it, with its current value.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ControlInfo {
    pub id: u32,
    /// The driver's name for it (varies across kernels; match on `id`).
    pub name: String,
    pub kind: ControlKind,
    pub min: i64,
    pub max: i64,
    pub step: u64,
    pub default: i64,
    /// The current value; none for buttons, classes, compound controls and unreadable ones.
    pub value: Option<i64>,
    /// The driver ignores writes (`V4L2_CTRL_FLAG_DISABLED`) or forbids them (`READ_ONLY`).
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub read_only: bool,
    /// Writable but without effect now (another control, e.g. an automatic mode, rules it).
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub inactive: bool,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub menu: Vec<MenuEntry>,
}

impl ControlInfo {
    /// `value` brought into the control's range and onto its steps (nearest step, from `min`).
    pub fn fit(&self, value: i64) -> i64 {
        let v = value.clamp(self.min, self.max.max(self.min));
        let step = self.step.max(1) as i64;
        let k = ((v - self.min) as f64 / step as f64).round() as i64;
        (self.min + k * step).min(self.max.max(self.min))
    }

    /// Whether a menu control offers entry `index` (true when the driver listed no entries).
    pub fn offers(&self, index: i64) -> bool {
        self.menu.is_empty() || self.menu.iter().any(|m| m.index == index)
    }
}

/// Reading and writing controls: a V4L2 device, or a scripted fake in tests.
pub trait Controls {
    /// Every control the device has, with its current value.
    fn controls(&mut self) -> Result<Vec<ControlInfo>>;
    /// The current value of control `id`.
    fn get_control(&mut self, id: u32) -> io::Result<i64>;
    /// Writes control `id` (the driver may clamp or round it; read it back to know).
    fn set_control(&mut self, id: u32, value: i64) -> io::Result<()>;
}

/// Mains frequency for the anti-flicker filter.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PowerLine {
    Off,
    #[serde(rename = "50hz")]
    Hz50,
    #[serde(rename = "60hz")]
    Hz60,
}

impl PowerLine {
    fn menu_index(self) -> i64 {
        match self {
            Self::Off => 0,
            Self::Hz50 => 1,
            Self::Hz60 => 2,
        }
    }
}

/// What to fix before calibration. `None` keeps the value the camera has when the lock starts
/// (for exposure, white balance and focus: what the automatic mode had settled on).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct LockSettings {
    /// Exposure time in 100 µs units (`V4L2_CID_EXPOSURE_ABSOLUTE`).
    pub exposure: Option<i64>,
    /// Gain in device units.
    pub gain: Option<i64>,
    /// White balance temperature in kelvin.
    pub white_balance: Option<i64>,
    /// Focus position in device units (larger is usually nearer).
    pub focus: Option<i64>,
    /// Backlight compensation in device units; `None` turns it off (0).
    pub backlight_compensation: Option<i64>,
    /// Mains frequency for the anti-flicker filter; `None` keeps the current setting.
    pub power_line: Option<PowerLine>,
}

/// The controls the lock touches.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    ExposureAuto,
    ExposureAutoPriority,
    Exposure,
    Gain,
    AutoWhiteBalance,
    WhiteBalance,
    FocusAuto,
    Focus,
    BacklightCompensation,
    PowerLine,
}

impl Role {
    pub fn cid(self) -> u32 {
        match self {
            Self::ExposureAuto => cid::EXPOSURE_AUTO,
            Self::ExposureAutoPriority => cid::EXPOSURE_AUTO_PRIORITY,
            Self::Exposure => cid::EXPOSURE_ABSOLUTE,
            Self::Gain => cid::GAIN,
            Self::AutoWhiteBalance => cid::AUTO_WHITE_BALANCE,
            Self::WhiteBalance => cid::WHITE_BALANCE_TEMPERATURE,
            Self::FocusAuto => cid::FOCUS_AUTO,
            Self::Focus => cid::FOCUS_ABSOLUTE,
            Self::BacklightCompensation => cid::BACKLIGHT_COMPENSATION,
            Self::PowerLine => cid::POWER_LINE_FREQUENCY,
        }
    }

    /// For reports: what it is and in which unit.
    pub fn label(self) -> &'static str {
        match self {
            Self::ExposureAuto => "exposure mode (1 manual)",
            Self::ExposureAutoPriority => "exposure may vary frame rate (0 no)",
            Self::Exposure => "exposure (100 µs)",
            Self::Gain => "gain",
            Self::AutoWhiteBalance => "auto white balance (0 off)",
            Self::WhiteBalance => "white balance (K)",
            Self::FocusAuto => "autofocus (0 off)",
            Self::Focus => "focus",
            Self::BacklightCompensation => "backlight compensation",
            Self::PowerLine => "power line (0 off, 1 50 Hz, 2 60 Hz)",
        }
    }
}

/// What became of one control.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case", tag = "status", content = "reason")]
pub enum Outcome {
    /// Read back as written.
    Accepted,
    /// Written, but the camera holds another value (rounded, clamped, or ruled by a mode).
    Adjusted,
    /// The write failed; the reason is the driver's.
    Rejected(String),
    /// Written, but it could not be read back.
    Unverified(String),
    /// The camera has no such control (not an error: many lack focus or white balance).
    Absent,
}

/// One control of a [`LockReport`].
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct Locked {
    pub role: Role,
    pub id: u32,
    /// The driver's name, when the control exists.
    pub name: Option<String>,
    /// The value asked for, before fitting it to the control's range and steps.
    pub requested: Option<i64>,
    /// The value read back after the lock.
    pub accepted: Option<i64>,
    #[serde(flatten)]
    pub outcome: Outcome,
}

/// The controls [`lock`] set: requested against accepted, per control.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct LockReport {
    pub controls: Vec<Locked>,
}

impl LockReport {
    pub fn get(&self, role: Role) -> Option<&Locked> {
        self.controls.iter().find(|c| c.role == role)
    }

    /// The exposure the camera holds, in 100 µs units.
    pub fn exposure(&self) -> Option<i64> {
        self.get(Role::Exposure).and_then(|c| c.accepted)
    }

    /// Whether automatic exposure is off, or the camera has no such switch. Calibration needs
    /// this: a camera that keeps adjusting its exposure makes the captures disagree.
    pub fn exposure_is_manual(&self) -> bool {
        self.get(Role::ExposureAuto).is_none_or(|c| {
            matches!(c.outcome, Outcome::Absent)
                || matches!(
                    c.accepted,
                    Some(EXPOSURE_MANUAL | EXPOSURE_SHUTTER_PRIORITY)
                )
        })
    }

    /// Controls that were written but do not hold what was asked.
    pub fn problems(&self) -> Vec<&Locked> {
        self.controls
            .iter()
            .filter(|c| !matches!(c.outcome, Outcome::Accepted | Outcome::Absent))
            .collect()
    }

    /// The accepted values as settings, to apply the same lock again (after a reconnect).
    pub fn settings(&self) -> LockSettings {
        let v = |r: Role| self.get(r).and_then(|c| c.accepted);
        LockSettings {
            exposure: v(Role::Exposure),
            gain: v(Role::Gain),
            white_balance: v(Role::WhiteBalance),
            focus: v(Role::Focus),
            backlight_compensation: v(Role::BacklightCompensation),
            power_line: match v(Role::PowerLine) {
                Some(0) => Some(PowerLine::Off),
                Some(1) => Some(PowerLine::Hz50),
                Some(2) => Some(PowerLine::Hz60),
                _ => None,
            },
        }
    }

    /// One line per control: "exposure (100 µs): requested 100, accepted 100".
    pub fn lines(&self) -> Vec<String> {
        let num = |v: Option<i64>| v.map_or("-".to_string(), |v| v.to_string());
        self.controls
            .iter()
            .map(|c| {
                let what = match &c.outcome {
                    Outcome::Accepted => "accepted".to_string(),
                    Outcome::Adjusted => "adjusted by the camera".to_string(),
                    Outcome::Rejected(r) => format!("rejected: {r}"),
                    Outcome::Unverified(r) => format!("not read back: {r}"),
                    Outcome::Absent => return format!("{}: the camera has none", c.role.label()),
                };
                format!(
                    "{}: requested {}, holds {} ({what})",
                    c.role.label(),
                    num(c.requested),
                    num(c.accepted)
                )
            })
            .collect()
    }
}

/// One planned write.
struct Step {
    role: Role,
    /// The value asked for (`None`: nothing to write, the control is only reported).
    requested: Option<i64>,
}

/// The writes of a lock, in order: each automatic mode off before its manual value, and the
/// exposure written once more at the end, since cameras reset or ignore it around the switch
/// to manual and when gain or white balance change. `now` reads a control's value before the
/// lock (what the automatic modes settled on).
fn plan(
    s: &LockSettings,
    info: impl Fn(Role) -> Option<ControlInfo>,
    now: impl Fn(Role) -> Option<i64>,
) -> Vec<Step> {
    let manual = info(Role::ExposureAuto).map(|c| {
        if c.offers(EXPOSURE_MANUAL) {
            EXPOSURE_MANUAL
        } else {
            EXPOSURE_SHUTTER_PRIORITY
        }
    });
    let keep = |v: Option<i64>, r: Role| v.or_else(|| now(r));
    let exposure = keep(s.exposure, Role::Exposure);
    let power = s
        .power_line
        .map(PowerLine::menu_index)
        .or_else(|| now(Role::PowerLine));
    let steps = [
        (Role::ExposureAuto, manual),
        (Role::ExposureAutoPriority, Some(0)),
        (Role::Exposure, exposure),
        (Role::Gain, keep(s.gain, Role::Gain)),
        (Role::AutoWhiteBalance, Some(0)),
        (
            Role::WhiteBalance,
            keep(s.white_balance, Role::WhiteBalance),
        ),
        (Role::FocusAuto, Some(0)),
        (Role::Focus, keep(s.focus, Role::Focus)),
        (
            Role::BacklightCompensation,
            Some(s.backlight_compensation.unwrap_or(0)),
        ),
        (Role::PowerLine, power),
        (Role::Exposure, exposure),
    ];
    steps
        .into_iter()
        .map(|(role, requested)| Step { role, requested })
        .collect()
}

/// Locks the camera for calibration: automatic exposure, white balance and focus off; exposure,
/// gain, white balance, focus, backlight compensation and power-line frequency written
/// (`settings`, or the values the camera holds when the lock starts), the exposure written
/// again after everything else; then every control read back. A control the camera lacks is
/// reported as absent, a write the driver refuses as rejected: neither is an error. Only
/// failing to list the controls at all is.
pub fn lock(dev: &mut dyn Controls, settings: &LockSettings) -> Result<LockReport> {
    let list = dev.controls()?;
    let info = |r: Role| list.iter().find(|c| c.id == r.cid()).cloned();
    let before: Vec<(Role, Option<i64>)> = ALL_ROLES
        .iter()
        .map(|&r| (r, info(r).and_then(|c| c.value)))
        .collect();
    let now = |r: Role| before.iter().find(|(x, _)| *x == r).and_then(|(_, v)| *v);
    let mut errors: Vec<(Role, String)> = Vec::new();
    let mut requested: Vec<(Role, Option<i64>)> = Vec::new();
    for step in plan(settings, info, now) {
        requested.retain(|(r, _)| *r != step.role);
        requested.push((step.role, step.requested));
        let (Some(c), Some(want)) = (info(step.role), step.requested) else {
            continue;
        };
        errors.retain(|(r, _)| *r != step.role);
        if c.read_only {
            errors.push((step.role, "the driver marks it read-only".into()));
        } else if let Err(e) = dev.set_control(c.id, c.fit(want)) {
            errors.push((step.role, e.to_string()));
        }
    }
    let controls = ALL_ROLES
        .iter()
        .map(|&role| {
            let want = requested
                .iter()
                .find(|(r, _)| *r == role)
                .and_then(|(_, v)| *v);
            report_one(dev, role, info(role), want, &errors)
        })
        .collect();
    Ok(LockReport { controls })
}

const ALL_ROLES: [Role; 10] = [
    Role::ExposureAuto,
    Role::ExposureAutoPriority,
    Role::Exposure,
    Role::Gain,
    Role::AutoWhiteBalance,
    Role::WhiteBalance,
    Role::FocusAuto,
    Role::Focus,
    Role::BacklightCompensation,
    Role::PowerLine,
];

/// Reads one control back and says what became of it.
fn report_one(
    dev: &mut dyn Controls,
    role: Role,
    info: Option<ControlInfo>,
    requested: Option<i64>,
    errors: &[(Role, String)],
) -> Locked {
    let Some(c) = info else {
        return Locked {
            role,
            id: role.cid(),
            name: None,
            requested,
            accepted: None,
            outcome: Outcome::Absent,
        };
    };
    let read = dev.get_control(c.id);
    let accepted = read.as_ref().ok().copied();
    let outcome = match (errors.iter().find(|(r, _)| *r == role), read) {
        (Some((_, e)), _) => Outcome::Rejected(e.clone()),
        (None, Err(e)) => Outcome::Unverified(e.to_string()),
        (None, Ok(v)) if requested.is_none_or(|r| c.fit(r) == v && r == v) => Outcome::Accepted,
        (None, Ok(_)) => Outcome::Adjusted,
    };
    Locked {
        role,
        id: c.id,
        name: Some(c.name),
        requested,
        accepted,
        outcome,
    }
}

/// Writes one control (fitted to its range and steps) and reads back what the camera holds.
pub fn set_and_read(dev: &mut dyn Controls, id: u32, value: i64) -> Result<i64> {
    let list = dev.controls()?;
    let value = list
        .iter()
        .find(|c| c.id == id)
        .map_or(value, |c| c.fit(value));
    dev.set_control(id, value)
        .and_then(|_| dev.get_control(id))
        .map_err(|e| crate::Error::Failed(format!("control {id:#x} = {value}: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn int(id: u32, min: i64, max: i64, step: u64, value: i64) -> ControlInfo {
        ControlInfo {
            id,
            name: format!("{id:#x}"),
            kind: ControlKind::Integer,
            min,
            max,
            step,
            default: min,
            value: Some(value),
            read_only: false,
            inactive: false,
            menu: vec![],
        }
    }

    #[test]
    fn values_are_fitted_to_range_and_step() {
        let c = int(1, 3, 2047, 4, 100);
        assert_eq!(c.fit(0), 3);
        assert_eq!(c.fit(5000), 2047);
        assert_eq!(c.fit(100), 99);
        assert_eq!(c.fit(102), 103);
        assert_eq!(int(1, 0, 10, 0, 0).fit(7), 7);
    }

    #[test]
    fn ids_are_the_kernels() {
        // linux/v4l2-controls.h: V4L2_CID_BASE + n and V4L2_CID_CAMERA_CLASS_BASE + n.
        let (base, camera) = (0x0098_0900, 0x009a_0900);
        assert_eq!(cid::AUTO_WHITE_BALANCE, base + 12);
        assert_eq!(cid::GAIN, base + 19);
        assert_eq!(cid::POWER_LINE_FREQUENCY, base + 24);
        assert_eq!(cid::WHITE_BALANCE_TEMPERATURE, base + 26);
        assert_eq!(cid::BACKLIGHT_COMPENSATION, base + 28);
        assert_eq!(cid::EXPOSURE_AUTO, camera + 1);
        assert_eq!(cid::EXPOSURE_ABSOLUTE, camera + 2);
        assert_eq!(cid::EXPOSURE_AUTO_PRIORITY, camera + 3);
        assert_eq!(cid::FOCUS_ABSOLUTE, camera + 10);
        assert_eq!(cid::FOCUS_AUTO, camera + 12);
    }

    #[test]
    fn the_plan_turns_modes_off_first_and_writes_exposure_last_again() {
        let s = LockSettings {
            exposure: Some(50),
            ..Default::default()
        };
        let info = |r: Role| Some(int(r.cid(), 0, 10_000, 1, 0));
        let steps = plan(&s, info, |_| Some(7));
        let roles: Vec<Role> = steps.iter().map(|s| s.role).collect();
        let pos = |r: Role| roles.iter().position(|&x| x == r).unwrap();
        assert!(pos(Role::ExposureAuto) < pos(Role::Exposure));
        assert!(pos(Role::AutoWhiteBalance) < pos(Role::WhiteBalance));
        assert!(pos(Role::FocusAuto) < pos(Role::Focus));
        assert_eq!(roles.last(), Some(&Role::Exposure));
        assert_eq!(steps.last().unwrap().requested, Some(50));
        // Unset values keep what the camera had.
        let gain = steps.iter().find(|s| s.role == Role::Gain).unwrap();
        assert_eq!(gain.requested, Some(7));
    }

    #[test]
    fn report_settings_round_trip() {
        let r = LockReport {
            controls: vec![
                Locked {
                    role: Role::Exposure,
                    id: cid::EXPOSURE_ABSOLUTE,
                    name: Some("Exposure Time, Absolute".into()),
                    requested: Some(100),
                    accepted: Some(98),
                    outcome: Outcome::Adjusted,
                },
                Locked {
                    role: Role::PowerLine,
                    id: cid::POWER_LINE_FREQUENCY,
                    name: None,
                    requested: Some(1),
                    accepted: Some(1),
                    outcome: Outcome::Accepted,
                },
            ],
        };
        let s = r.settings();
        assert_eq!(s.exposure, Some(98));
        assert_eq!(s.power_line, Some(PowerLine::Hz50));
        assert_eq!(r.problems().len(), 1);
        assert!(r.lines()[0].contains("requested 100, holds 98"));
        let json = serde_json::to_value(&r).unwrap();
        assert_eq!(json["controls"][0]["status"], "adjusted");
        assert_eq!(json["controls"][0]["role"], "exposure");
    }
}
