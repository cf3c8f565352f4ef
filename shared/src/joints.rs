//! The Nao joint table: names, stable ids, limits and velocity limits.
//!
//! Limits come from the published URDF (`nao_description`), as listed in the mission document.
//! The right arm mirrors the left: pitch and yaw limits are the same, roll limits swap sign.
//! Joints without a row here (legs, hands) have no known limits, and a command for them is
//! refused: the firmware never sends what it cannot check.

use core::fmt;
use serde::{Deserialize, Serialize};

/// Position and velocity limits of one joint, in rad and rad/s.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointLimits {
    /// Lowest angle that may be commanded, rad.
    pub min: f32,
    /// Highest angle that may be commanded, rad.
    pub max: f32,
    /// Largest speed, rad/s (absolute).
    pub max_velocity: f32,
}

/// Why an angle or a joint id was refused.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum JointError {
    /// No joint has this numeric id.
    UnknownId(u8),
    /// The joint has no limits in the table, so it may not be commanded.
    NoLimits(Joint),
    /// NaN or infinite.
    NotFinite(Joint),
    /// Finite but outside `[min, max]`.
    /// `joint` is the joint asked for, `angle` the refused value in rad.
    #[allow(missing_docs)]
    OutOfRange { joint: Joint, angle: f32 },
}

impl fmt::Display for JointError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            JointError::UnknownId(id) => write!(f, "unknown joint id {id}"),
            JointError::NoLimits(j) => write!(f, "joint {} has no known limits", j.name()),
            JointError::NotFinite(j) => write!(f, "angle for {} is not finite", j.name()),
            JointError::OutOfRange { joint, angle } => {
                let l = joint.limits().expect("OutOfRange is only made for limited joints");
                write!(
                    f,
                    "angle {angle} rad for {} is outside [{}, {}]",
                    joint.name(),
                    l.min,
                    l.max
                )
            }
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for JointError {}

macro_rules! joints {
    ($($name:ident = $id:literal),* $(,)?) => {
        /// One of Nao's 25 joints. The discriminant is the stable wire id (NAOqi body order).
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
        #[serde(try_from = "u8", into = "u8")]
        #[repr(u8)]
        /// Each variant is the NAOqi joint of that name, e.g. `LShoulderPitch` the left shoulder pitch.
        #[allow(missing_docs)]
        pub enum Joint { $($name = $id),* }

        impl Joint {
            /// All joints in id order.
            pub const ALL: [Joint; 25] = [$(Joint::$name),*];

            /// The NAOqi name, e.g. `"LShoulderPitch"`.
            pub const fn name(self) -> &'static str {
                match self { $(Joint::$name => stringify!($name)),* }
            }
        }
    };
}

joints! {
    HeadYaw = 0, HeadPitch = 1,
    LShoulderPitch = 2, LShoulderRoll = 3, LElbowYaw = 4, LElbowRoll = 5, LWristYaw = 6, LHand = 7,
    LHipYawPitch = 8, LHipRoll = 9, LHipPitch = 10, LKneePitch = 11, LAnklePitch = 12, LAnkleRoll = 13,
    RHipRoll = 14, RHipPitch = 15, RKneePitch = 16, RAnklePitch = 17, RAnkleRoll = 18,
    RShoulderPitch = 19, RShoulderRoll = 20, RElbowYaw = 21, RElbowRoll = 22, RWristYaw = 23, RHand = 24,
}

const fn lim(min: f32, max: f32, max_velocity: f32) -> Option<JointLimits> {
    Some(JointLimits { min, max, max_velocity })
}

impl Joint {
    /// The stable wire id (0..=24, NAOqi body order), as carried in messages.
    pub const fn id(self) -> u8 {
        self as u8
    }

    /// The joint with wire id `id`, or [`JointError::UnknownId`] for 25 and above.
    pub const fn from_id(id: u8) -> Result<Joint, JointError> {
        if (id as usize) < Joint::ALL.len() {
            Ok(Joint::ALL[id as usize])
        } else {
            Err(JointError::UnknownId(id))
        }
    }

    /// Looks a joint up by its NAOqi name.
    pub fn from_name(name: &str) -> Option<Joint> {
        Joint::ALL.iter().copied().find(|j| j.name() == name)
    }

    /// Limits for the head and both arms; `None` for legs and hands.
    pub const fn limits(self) -> Option<JointLimits> {
        use Joint::*;
        match self {
            HeadYaw => lim(-2.08567, 2.08567, 8.26797),
            HeadPitch => lim(-0.671952, 0.514872, 7.19407),
            LShoulderPitch | RShoulderPitch => lim(-2.08567, 2.08567, 8.26797),
            LShoulderRoll => lim(-0.314159, 1.32645, 7.19407),
            RShoulderRoll => lim(-1.32645, 0.314159, 7.19407),
            LElbowYaw | RElbowYaw => lim(-2.08567, 2.08567, 8.26797),
            LElbowRoll => lim(-1.54462, -0.0349066, 7.19407),
            RElbowRoll => lim(0.0349066, 1.54462, 7.19407),
            LWristYaw | RWristYaw => lim(-1.82387, 1.82387, 24.6229),
            _ => None,
        }
    }

    /// Checks that `angle` may be commanded: finite, inside the limits, on a limited joint.
    pub fn validate(self, angle: f32) -> Result<f32, JointError> {
        let l = self.limits().ok_or(JointError::NoLimits(self))?;
        if !angle.is_finite() {
            return Err(JointError::NotFinite(self));
        }
        if angle < l.min || angle > l.max {
            return Err(JointError::OutOfRange { joint: self, angle });
        }
        Ok(angle)
    }

    /// Clamps a finite angle into the limits. NaN and unlimited joints are still errors:
    /// clamping must never invent a position.
    pub fn clamp(self, angle: f32) -> Result<f32, JointError> {
        let l = self.limits().ok_or(JointError::NoLimits(self))?;
        if angle.is_nan() {
            return Err(JointError::NotFinite(self));
        }
        // Not `f32::clamp`: its `min <= max` check formats both floats when it fails, which
        // links float printing into the size-budgeted board image. The limits are ordered.
        Ok(if angle < l.min {
            l.min
        } else if angle > l.max {
            l.max
        } else {
            angle
        })
    }
}

impl From<Joint> for u8 {
    fn from(j: Joint) -> u8 {
        j as u8
    }
}

impl TryFrom<u8> for Joint {
    type Error = JointError;
    fn try_from(id: u8) -> Result<Joint, JointError> {
        Joint::from_id(id)
    }
}

impl fmt::Display for Joint {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The five joints the reach network drives, in its output order.
pub const REACH_JOINTS: [Joint; 5] = [
    Joint::HeadYaw,
    Joint::HeadPitch,
    Joint::LShoulderPitch,
    Joint::LShoulderRoll,
    Joint::LElbowRoll,
];

/// The published home posture for [`REACH_JOINTS`]: head straight, left arm down.
pub const HOME_POSTURE: [f32; 5] = [0.0, 0.0, 1.402034, 0.133416, -0.981718];

/// The published robot moved at this fraction of each joint's maximum velocity.
pub const DEFAULT_SPEED_FRACTION: f32 = 0.1;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_are_dense_and_round_trip() {
        for (i, j) in Joint::ALL.iter().enumerate() {
            assert_eq!(j.id() as usize, i);
            assert_eq!(Joint::from_id(i as u8), Ok(*j));
            assert_eq!(Joint::from_name(j.name()), Some(*j));
        }
        assert_eq!(Joint::from_id(25), Err(JointError::UnknownId(25)));
        assert_eq!(Joint::from_name("Nose"), None);
    }

    #[test]
    fn table_matches_the_urdf_numbers() {
        let l = Joint::HeadPitch.limits().unwrap();
        assert_eq!((l.min, l.max, l.max_velocity), (-0.671952, 0.514872, 7.19407));
        let l = Joint::LElbowRoll.limits().unwrap();
        assert_eq!((l.min, l.max), (-1.54462, -0.0349066));
        // Right arm rolls mirror the left ones.
        for (l, r) in [
            (Joint::LShoulderRoll, Joint::RShoulderRoll),
            (Joint::LElbowRoll, Joint::RElbowRoll),
        ] {
            let (l, r) = (l.limits().unwrap(), r.limits().unwrap());
            assert_eq!((l.min, l.max), (-r.max, -r.min));
        }
        assert_eq!(Joint::LWristYaw.limits().unwrap().max_velocity, 24.6229);
        assert!(Joint::LHand.limits().is_none());
        assert!(Joint::RKneePitch.limits().is_none());
    }

    #[test]
    fn validate_and_clamp() {
        assert_eq!(Joint::HeadYaw.validate(0.5), Ok(0.5));
        assert!(matches!(
            Joint::HeadPitch.validate(0.6),
            Err(JointError::OutOfRange { .. })
        ));
        assert_eq!(
            Joint::HeadYaw.validate(f32::NAN),
            Err(JointError::NotFinite(Joint::HeadYaw))
        );
        assert_eq!(
            Joint::HeadYaw.validate(f32::INFINITY),
            Err(JointError::NotFinite(Joint::HeadYaw))
        );
        assert_eq!(
            Joint::LKneePitch.validate(0.0),
            Err(JointError::NoLimits(Joint::LKneePitch))
        );
        assert_eq!(Joint::HeadPitch.clamp(9.0), Ok(0.514872));
        assert_eq!(Joint::HeadPitch.clamp(f32::NEG_INFINITY), Ok(-0.671952));
        assert!(Joint::HeadPitch.clamp(f32::NAN).is_err());
    }

    #[test]
    fn home_posture_is_inside_the_limits() {
        for (j, a) in REACH_JOINTS.iter().zip(HOME_POSTURE) {
            assert_eq!(j.validate(a), Ok(a), "{j}");
        }
    }

    #[test]
    fn wire_form_is_the_id() {
        let mut buf = [0u8; 4];
        let out = postcard::to_slice(&Joint::LElbowRoll, &mut buf).unwrap();
        assert_eq!(out, &[5]);
        assert_eq!(postcard::from_bytes::<Joint>(&[24]), Ok(Joint::RHand));
        assert!(postcard::from_bytes::<Joint>(&[25]).is_err());
    }
}
