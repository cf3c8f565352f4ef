//! From joint angles to a servo's raw counts and back: one [`JointMapEntry`] per joint (ID,
//! direction, raw count at 0 rad, counts per radian, raw limits), checked as a whole so that no
//! target inside a map's raw limits can leave the joint's limits.

use crate::joints::{Joint, REACH_JOINTS};
use serde::{Deserialize, Serialize};

use super::table::COUNTS_PER_TURN;
use super::MAX_ID;

/// Joints a map covers: those the board commands and reads (head, left arm).
pub const MAP_JOINTS: usize = REACH_JOINTS.len();

/// Counts per radian of the X series (4096 per turn).
pub const X_COUNTS_PER_RAD: f32 = COUNTS_PER_TURN as f32 / core::f32::consts::TAU;

/// How one joint sits on its servo.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct JointMapEntry {
    /// The joint this servo drives.
    pub joint: Joint,
    /// Dynamixel ID, 1..=252.
    pub id: u8,
    /// The servo turns the joint's way (`false`: the opposite way).
    pub forward: bool,
    /// Raw count at 0 rad.
    pub zero: i32,
    /// Raw counts per radian of joint motion (> 0; [`X_COUNTS_PER_RAD`] for a direct drive).
    pub counts_per_rad: f32,
    /// The servo's own Min/Max Position Limit, written at start-up.
    pub raw_min: i32,
    /// See `raw_min`; `raw_min <= raw_max`, both in 0..=4095.
    pub raw_max: i32,
}

/// Why a map, or a conversion through it, was refused.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum MapError {
    /// An ID of 0 or above 252, or one used twice.
    /// `joint`: the entry at fault.
    #[allow(missing_docs)]
    BadId { joint: Joint },
    /// A joint without limits, or one listed twice.
    /// `joint`: the entry at fault.
    #[allow(missing_docs)]
    BadJoint { joint: Joint },
    /// Counts per radian not finite, not positive, or a zero outside the encoder's range.
    /// `joint`: the entry at fault.
    #[allow(missing_docs)]
    BadScale { joint: Joint },
    /// Raw limits reversed or outside 0..=4095.
    /// `joint`: the entry at fault.
    #[allow(missing_docs)]
    BadRawLimits { joint: Joint },
    /// A raw limit that lands outside the joint's limits (rad): the servo could be sent there.
    /// `joint`: the entry at fault.
    #[allow(missing_docs)]
    LeavesLimits { joint: Joint },
    /// A target outside the joint's limits (rad) or not finite.
    /// `joint`: the joint the target was for.
    #[allow(missing_docs)]
    TargetOutOfRange { joint: Joint },
    /// A target that, converted, falls outside the raw limits.
    /// `joint`: the joint the target was for; `raw`: the converted target, counts.
    #[allow(missing_docs)]
    RawOutOfRange { joint: Joint, raw: i32 },
}

impl JointMapEntry {
    /// The entry for the emulated robot's X-series servo: centre (2048) at 0 rad, raw limits
    /// the joint's limits rounded inwards.
    pub fn x_series(joint: Joint, id: u8, forward: bool) -> JointMapEntry {
        let mut e = JointMapEntry {
            joint,
            id,
            forward,
            zero: (COUNTS_PER_TURN / 2) as i32,
            counts_per_rad: X_COUNTS_PER_RAD,
            raw_min: 0,
            raw_max: 0,
        };
        if let Some(l) = joint.limits() {
            let (a, b) = (e.raw_exact(l.min), e.raw_exact(l.max));
            let (lo, hi) = if a < b { (a, b) } else { (b, a) };
            e.raw_min = ceil(lo);
            e.raw_max = floor(hi);
        }
        e
    }

    fn sign(&self) -> f32 {
        if self.forward {
            1.0
        } else {
            -1.0
        }
    }

    fn raw_exact(&self, rad: f32) -> f32 {
        self.zero as f32 + self.sign() * rad * self.counts_per_rad
    }

    /// The angle of a raw count.
    pub fn to_rad(&self, raw: i32) -> f32 {
        (raw - self.zero) as f32 * self.sign() / self.counts_per_rad
    }

    /// The raw count for a target: refused outside the joint's limits (before conversion) and
    /// outside the raw limits (after). Rounding may land one count outside a raw limit that
    /// was rounded inwards; that count is taken back to the limit, anything more is refused.
    pub fn to_raw(&self, rad: f32) -> Result<i32, MapError> {
        let joint = self.joint;
        if self.joint.validate(rad).is_err() {
            return Err(MapError::TargetOutOfRange { joint });
        }
        let raw = round(self.raw_exact(rad));
        let raw = if raw == self.raw_min - 1 {
            self.raw_min
        } else if raw == self.raw_max + 1 {
            self.raw_max
        } else {
            raw
        };
        if raw < self.raw_min || raw > self.raw_max {
            return Err(MapError::RawOutOfRange { joint, raw });
        }
        Ok(raw)
    }

    /// Checks this entry alone (IDs across entries: [`check_map`]).
    pub fn check(&self) -> Result<(), MapError> {
        let joint = self.joint;
        let Some(l) = joint.limits() else {
            return Err(MapError::BadJoint { joint });
        };
        if self.id == 0 || self.id > MAX_ID {
            return Err(MapError::BadId { joint });
        }
        let max_raw = COUNTS_PER_TURN as i32 - 1;
        let scale_ok = self.counts_per_rad.is_finite() && self.counts_per_rad > 0.0;
        if !(scale_ok && (0..=max_raw).contains(&self.zero)) {
            return Err(MapError::BadScale { joint });
        }
        if self.raw_min > self.raw_max || self.raw_min < 0 || self.raw_max > max_raw {
            return Err(MapError::BadRawLimits { joint });
        }
        for raw in [self.raw_min, self.raw_max] {
            let a = self.to_rad(raw);
            if !(a >= l.min && a <= l.max) {
                return Err(MapError::LeavesLimits { joint });
            }
        }
        Ok(())
    }
}

/// Checks every entry and that IDs and joints are each used once.
pub fn check_map(map: &[JointMapEntry]) -> Result<(), MapError> {
    for (i, e) in map.iter().enumerate() {
        e.check()?;
        for f in &map[..i] {
            if f.id == e.id {
                return Err(MapError::BadId { joint: e.joint });
            }
            if f.joint == e.joint {
                return Err(MapError::BadJoint { joint: e.joint });
            }
        }
    }
    Ok(())
}

/// The emulated robot's map for [`REACH_JOINTS`]: ID = joint id + 1, the head's pitch servo
/// mounted the other way round.
pub fn default_map() -> [JointMapEntry; MAP_JOINTS] {
    REACH_JOINTS.map(|j| JointMapEntry::x_series(j, j.id() + 1, j != Joint::HeadPitch))
}

// `core` has no float rounding; these are exact for the encoder's range.
fn floor(x: f32) -> i32 {
    let t = x as i32;
    if (t as f32) > x {
        t - 1
    } else {
        t
    }
}

fn ceil(x: f32) -> i32 {
    -floor(-x)
}

fn round(x: f32) -> i32 {
    floor(x + 0.5)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_map_is_valid_and_round_trips() {
        let map = default_map();
        check_map(&map).unwrap();
        for e in map {
            let l = e.joint.limits().unwrap();
            for a in [l.min, l.max, 0.5 * (l.min + l.max)] {
                let raw = e.to_raw(a).unwrap();
                assert!((e.raw_min..=e.raw_max).contains(&raw));
                assert!((e.to_rad(raw) - a).abs() <= 1.01 / e.counts_per_rad, "{e:?} {a}");
            }
            assert!(e.to_raw(l.max + 0.01).is_err());
            assert!(e.to_raw(f32::NAN).is_err());
        }
        // HeadYaw 0 rad is the centre; HeadPitch turns the other way.
        assert_eq!(map[0].to_raw(0.0), Ok(2048));
        assert_eq!(map[1].to_raw(0.1), Ok(2048 - 65));
    }

    #[test]
    fn maps_that_let_a_target_out_are_refused() {
        let good = default_map();
        let mut m = good;
        m[2].raw_max += 10;
        assert_eq!(check_map(&m), Err(MapError::LeavesLimits { joint: m[2].joint }));
        let mut m = good;
        m[0].counts_per_rad = 100.0; // limits rad -> fewer counts: raw limits now too wide
        assert_eq!(check_map(&m), Err(MapError::LeavesLimits { joint: m[0].joint }));
        let mut m = good;
        m[1].forward = true; // pitch limits are not symmetric
        assert_eq!(check_map(&m), Err(MapError::LeavesLimits { joint: m[1].joint }));
        let mut m = good;
        m[3].id = m[4].id;
        assert_eq!(check_map(&m), Err(MapError::BadId { joint: m[4].joint }));
        let mut m = good;
        m[0].id = 0;
        assert!(check_map(&m).is_err());
        let mut m = good;
        m[0].counts_per_rad = f32::NAN;
        assert!(check_map(&m).is_err());
        let mut m = good;
        m[0].raw_min = m[0].raw_max + 1;
        assert!(check_map(&m).is_err());
        let mut m = good;
        m[0].joint = Joint::LHand;
        assert!(check_map(&m).is_err());
        // A narrower raw range is fine, and targets outside it are refused after conversion.
        let mut m = good;
        m[0].raw_max = 2100;
        check_map(&m).unwrap();
        assert!(matches!(m[0].to_raw(1.0), Err(MapError::RawOutOfRange { .. })));
    }
}
