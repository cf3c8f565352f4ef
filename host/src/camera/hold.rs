//! Holding a camera still: its automatic exposure, gain and white balance switched to manual at
//! fixed values, so that the picture changes only when the room does.
//!
//! The decision is a pure function ([`plan`]) over a description of the driver's controls
//! ([`Control`]) and the values to hold; the V4L2 device code (`v4l2.rs`) builds the description
//! from the device's queried controls, reads the values and carries the plan out.
//!
//! Controls, as the V4L2 specification names them (ids from `videodev2.h`/`v4l2-controls.h`):
//! `V4L2_CID_EXPOSURE_AUTO` (0x009a0901, a menu: 0 auto, 1 manual, 2 shutter priority,
//! 3 aperture priority), `V4L2_CID_EXPOSURE_ABSOLUTE` (0x009a0902, 100 us units),
//! `V4L2_CID_AUTOGAIN` (0x00980912, boolean), `V4L2_CID_GAIN` (0x00980913),
//! `V4L2_CID_AUTO_WHITE_BALANCE` (0x0098090c, boolean), `V4L2_CID_WHITE_BALANCE_TEMPERATURE`
//! (0x0098091a, kelvin).
use std::collections::BTreeMap;

/// A control this holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Ctl {
    /// `V4L2_CID_EXPOSURE_AUTO`: the automatic exposure's mode (a menu).
    ExposureAuto,
    /// `V4L2_CID_EXPOSURE_ABSOLUTE`: the exposure time, 100 us units.
    ExposureAbsolute,
    /// `V4L2_CID_AUTOGAIN`: the automatic gain, on or off.
    Autogain,
    /// `V4L2_CID_GAIN`: the gain, in the driver's units.
    Gain,
    /// `V4L2_CID_AUTO_WHITE_BALANCE`: the automatic white balance, on or off.
    AutoWhiteBalance,
    /// `V4L2_CID_WHITE_BALANCE_TEMPERATURE`: the white balance, kelvin.
    WhiteBalanceTemperature,
}

impl Ctl {
    /// Every control this holds, automatic switch before the value it drives.
    pub const ALL: [Ctl; 6] = [
        Ctl::ExposureAuto,
        Ctl::ExposureAbsolute,
        Ctl::Autogain,
        Ctl::Gain,
        Ctl::AutoWhiteBalance,
        Ctl::WhiteBalanceTemperature,
    ];

    /// The name the values are stored under (`dataset.json`'s `camera_controls`): the V4L2 id
    /// without `V4L2_CID_`, in lower case.
    pub fn name(self) -> &'static str {
        match self {
            Ctl::ExposureAuto => "exposure_auto",
            Ctl::ExposureAbsolute => "exposure_absolute",
            Ctl::Autogain => "autogain",
            Ctl::Gain => "gain",
            Ctl::AutoWhiteBalance => "auto_white_balance",
            Ctl::WhiteBalanceTemperature => "white_balance_temperature",
        }
    }
}

/// `V4L2_EXPOSURE_MANUAL`, the manual entry of the `EXPOSURE_AUTO` menu.
pub const EXPOSURE_MANUAL: i32 = 1;

/// What a driver says about one of its controls (VIDIOC_QUERYCTRL, and VIDIOC_QUERYMENU for a
/// menu's valid entries).
#[derive(Clone, Debug, PartialEq)]
pub struct Control {
    /// Which control.
    pub ctl: Ctl,
    /// The values it takes: a number, a switch or a menu.
    pub kind: Kind,
    /// Its least value.
    pub min: i32,
    /// Its greatest value.
    pub max: i32,
    /// The driver refuses writes to it (`V4L2_CTRL_FLAG_READ_ONLY`).
    pub read_only: bool,
}

/// The type of a control's value, as the driver reports it.
#[derive(Clone, Debug, PartialEq)]
pub enum Kind {
    /// A number from `min` to `max`.
    Integer,
    /// A switch: 0 off, 1 on.
    Boolean,
    /// The valid entries of a menu (drivers may leave gaps).
    Menu(Vec<i32>),
}

/// One thing that moves the picture by itself: an automatic switch and the value it drives.
struct Group {
    what: &'static str,
    auto: Ctl,
    value: Ctl,
}

const GROUPS: [Group; 3] = [
    Group { what: "exposure", auto: Ctl::ExposureAuto, value: Ctl::ExposureAbsolute },
    Group { what: "gain", auto: Ctl::Autogain, value: Ctl::Gain },
    Group { what: "white balance", auto: Ctl::AutoWhiteBalance, value: Ctl::WhiteBalanceTemperature },
];

/// Writes for one group, in order; a write that the driver refuses skips the rest of its group.
#[derive(Clone, Debug, PartialEq)]
pub struct Step {
    /// The group, as notes name it: `exposure`, `gain` or `white balance`.
    pub what: &'static str,
    /// The controls to set and their values, in the order to write them.
    pub writes: Vec<(Ctl, i32)>,
}

/// What [`plan`] decided.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Plan {
    /// The writes, group by group.
    pub steps: Vec<Step>,
    /// One line for each group left as it is, or held without a value to store.
    pub notes: Vec<String>,
    /// The values held, by [`Ctl::name`]: what `msr record` stores.
    pub held: BTreeMap<String, i32>,
}

/// How to hold the camera: for each group, the automatic switch off first (`EXPOSURE_AUTO` to
/// manual, `AUTOGAIN` and `AUTO_WHITE_BALANCE` to 0), then its value. `values` are those to hold
/// (read from the device once the picture settled, or a recording's), by [`Ctl::name`]. A group
/// the driver lacks, or whose value it cannot take, is left as it is with a note; a group with
/// only its automatic switch is switched off (held where the automatic left it, nothing stored).
pub fn plan(driver: &[Control], values: &BTreeMap<String, i32>) -> Plan {
    let find = |c: Ctl| driver.iter().find(|d| d.ctl == c);
    let mut p = Plan::default();
    for g in &GROUPS {
        let (auto, value) = (find(g.auto), find(g.value));
        // The write that switches the automatic off, or why it cannot be.
        let off = match auto {
            None => Ok(None),
            Some(a) if a.read_only => Err(format!("{} is read-only", g.auto.name())),
            Some(a) => match &a.kind {
                Kind::Menu(entries) if entries.contains(&EXPOSURE_MANUAL) => Ok(Some((g.auto, EXPOSURE_MANUAL))),
                Kind::Menu(entries) => Err(format!("{} has no manual entry (menu {entries:?})", g.auto.name())),
                _ if (a.min..=a.max).contains(&0) => Ok(Some((g.auto, 0))),
                _ => Err(format!("{} cannot be set to 0 ({}..={})", g.auto.name(), a.min, a.max)),
            },
        };
        let off = match off {
            Ok(o) => o,
            Err(why) => {
                p.notes.push(format!("{}: left as it is: {why}", g.what));
                continue;
            }
        };
        let Some(v) = value else {
            match off {
                Some(w) => {
                    p.notes.push(format!(
                        "{}: the driver has no {}: held where the automatic left it, no value stored",
                        g.what,
                        g.value.name()
                    ));
                    p.steps.push(Step { what: g.what, writes: vec![w] });
                }
                None => p.notes.push(format!("{}: the driver has no such control: skipped", g.what)),
            }
            continue;
        };
        let Some(&x) = values.get(g.value.name()) else {
            p.notes.push(format!("{}: no {} value to hold: left as it is", g.what, g.value.name()));
            continue;
        };
        if v.read_only {
            p.notes.push(format!("{}: {} is read-only: left as it is", g.what, g.value.name()));
            continue;
        }
        if !(v.min..=v.max).contains(&x) {
            p.notes.push(format!(
                "{}: {} {x} is outside the driver's {}..={}: left as it is",
                g.what,
                g.value.name(),
                v.min,
                v.max
            ));
            continue;
        }
        p.steps.push(Step { what: g.what, writes: off.into_iter().chain([(g.value, x)]).collect() });
        p.held.insert(g.value.name().to_string(), x);
    }
    p
}

/// The value controls whose current values [`plan`] wants, among those the driver has.
pub fn values_to_read(driver: &[Control]) -> Vec<Ctl> {
    GROUPS.iter().map(|g| g.value).filter(|c| driver.iter().any(|d| d.ctl == *c)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn int(ctl: Ctl, min: i32, max: i32) -> Control {
        Control { ctl, kind: Kind::Integer, min, max, read_only: false }
    }

    fn boolean(ctl: Ctl) -> Control {
        Control { ctl, kind: Kind::Boolean, min: 0, max: 1, read_only: false }
    }

    fn values(v: &[(&str, i32)]) -> BTreeMap<String, i32> {
        v.iter().map(|(k, v)| (k.to_string(), *v)).collect()
    }

    /// A typical UVC webcam: exposure menu {1 manual, 3 aperture priority}, exposure 3..2047,
    /// gain 0..255 without autogain, white balance automatic and 2800..6500 K.
    fn webcam() -> Vec<Control> {
        vec![
            Control { ctl: Ctl::ExposureAuto, kind: Kind::Menu(vec![1, 3]), min: 0, max: 3, read_only: false },
            int(Ctl::ExposureAbsolute, 3, 2047),
            int(Ctl::Gain, 0, 255),
            boolean(Ctl::AutoWhiteBalance),
            int(Ctl::WhiteBalanceTemperature, 2800, 6500),
        ]
    }

    #[test]
    fn a_webcam_gets_each_automatic_off_before_its_value() {
        let p = plan(&webcam(), &values(&[("exposure_absolute", 156), ("gain", 64), ("white_balance_temperature", 4600)]));
        assert_eq!(
            p.steps,
            vec![
                Step { what: "exposure", writes: vec![(Ctl::ExposureAuto, 1), (Ctl::ExposureAbsolute, 156)] },
                Step { what: "gain", writes: vec![(Ctl::Gain, 64)] },
                Step { what: "white balance", writes: vec![(Ctl::AutoWhiteBalance, 0), (Ctl::WhiteBalanceTemperature, 4600)] },
            ]
        );
        assert_eq!(p.held, values(&[("exposure_absolute", 156), ("gain", 64), ("white_balance_temperature", 4600)]));
        assert!(p.notes.is_empty(), "{:?}", p.notes);
    }

    #[test]
    fn a_driver_with_only_gain_holds_gain_and_says_what_it_lacks() {
        let p = plan(&[int(Ctl::Gain, 0, 100), boolean(Ctl::Autogain)], &values(&[("gain", 7), ("exposure_absolute", 99)]));
        assert_eq!(p.steps, vec![Step { what: "gain", writes: vec![(Ctl::Autogain, 0), (Ctl::Gain, 7)] }]);
        assert_eq!(p.held, values(&[("gain", 7)]));
        assert_eq!(p.notes.len(), 2, "{:?}", p.notes);
        assert!(p.notes[0].starts_with("exposure: the driver has no such control"), "{:?}", p.notes);
        assert!(p.notes[1].starts_with("white balance: the driver has no such control"), "{:?}", p.notes);
    }

    #[test]
    fn a_driver_without_controls_writes_nothing() {
        let p = plan(&[], &values(&[("gain", 7)]));
        assert!(p.steps.is_empty() && p.held.is_empty());
        assert_eq!(p.notes.len(), 3, "{:?}", p.notes);
        assert!(values_to_read(&[]).is_empty());
    }

    #[test]
    fn a_menu_without_manual_or_a_value_out_of_range_leaves_the_group_on_auto() {
        let mut d = webcam();
        d[0].kind = Kind::Menu(vec![0, 3]);
        // A recording from another camera: its temperature is beyond this one's range.
        let p = plan(&d, &values(&[("exposure_absolute", 156), ("gain", 64), ("white_balance_temperature", 9000)]));
        assert_eq!(p.steps, vec![Step { what: "gain", writes: vec![(Ctl::Gain, 64)] }]);
        assert!(p.notes[0].contains("no manual entry (menu [0, 3])"), "{:?}", p.notes);
        assert!(p.notes[1].contains("9000 is outside the driver's 2800..=6500"), "{:?}", p.notes);
        assert_eq!(p.held, values(&[("gain", 64)]));
    }

    #[test]
    fn an_automatic_without_its_value_is_switched_off_and_a_missing_value_leaves_it_on() {
        // White balance automatic, no temperature (red/blue balance instead): frozen where it is.
        let d = vec![boolean(Ctl::AutoWhiteBalance), boolean(Ctl::Autogain), int(Ctl::Gain, 0, 10)];
        let p = plan(&d, &values(&[]));
        assert_eq!(p.steps, vec![Step { what: "white balance", writes: vec![(Ctl::AutoWhiteBalance, 0)] }]);
        assert!(p.held.is_empty());
        assert!(p.notes.iter().any(|n| n.contains("no gain value to hold")), "{:?}", p.notes);
        assert_eq!(values_to_read(&d), vec![Ctl::Gain]);
        assert_eq!(values_to_read(&webcam()), vec![Ctl::ExposureAbsolute, Ctl::Gain, Ctl::WhiteBalanceTemperature]);
    }

    #[test]
    fn a_read_only_control_is_not_written() {
        let mut d = webcam();
        d[2].read_only = true;
        let p = plan(&d, &values(&[("exposure_absolute", 10), ("gain", 64), ("white_balance_temperature", 5000)]));
        assert!(p.steps.iter().all(|s| s.what != "gain"));
        assert!(p.notes.iter().any(|n| n == "gain: gain is read-only: left as it is"), "{:?}", p.notes);
    }
}
