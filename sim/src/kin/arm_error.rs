//! An arm that is not its drawing: joint zeros off and links of other lengths than the URDF's.
//!
//! The board, the trainer and the sim's inverse kinematics know the drawing (`kin`'s constants).
//! A real arm differs: a replaced servo's zero sits a degree or two away, links are a few percent
//! from the drawing. The sim's arm can be such an arm: rendering and the touch judge use it, the
//! rest of the method does not know it.
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// How the sim's left arm differs from its drawing.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ArmError {
    /// Added to each left-arm joint's angle, in the order of [`super::LeftArm`]'s fields
    /// (shoulder pitch, shoulder roll, elbow yaw, elbow roll, wrist yaw), radians: where the joint
    /// really is when its servo reports 0.
    pub zero_rad: [f64; 5],
    /// Factors on the lengths of the upper arm, the forearm and the hand (1: the drawing).
    pub length: [f64; 3],
}

/// The most an arm error of a level may be: joint zeros within `+-deg`, lengths within `+-share`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ArmErrorBound {
    /// Largest joint zero offset, degrees.
    pub deg: f64,
    /// Largest relative length error.
    pub share: f64,
}

impl ArmError {
    /// The drawing itself.
    pub const EXACT: ArmError = ArmError { zero_rad: [0.0; 5], length: [1.0; 3] };

    /// The levels of `--arm-error`: 0 exact, 1 zeros within +-1.5 deg and lengths within
    /// +-2.5 %, 2 within +-3 deg and +-5 %.
    pub const LEVELS: [ArmErrorBound; 3] = [
        ArmErrorBound { deg: 0.0, share: 0.0 },
        ArmErrorBound { deg: 1.5, share: 0.025 },
        ArmErrorBound { deg: 3.0, share: 0.05 },
    ];

    /// One robot's arm at `level` (0, 1 or 2), drawn uniformly within the level's bounds from
    /// `seed`; the same seed and level give the same arm. `None` for an unknown level.
    pub fn draw(level: u8, seed: u64) -> Option<ArmError> {
        let b = *Self::LEVELS.get(level as usize)?;
        if level == 0 {
            return Some(Self::EXACT);
        }
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x61726d5f6572726f);
        let mut e = Self::EXACT;
        for z in &mut e.zero_rad {
            *z = rng.gen_range(-b.deg..=b.deg).to_radians();
        }
        for l in &mut e.length {
            *l = 1.0 + rng.gen_range(-b.share..=b.share);
        }
        Some(e)
    }

    /// Whether this is the drawing.
    pub fn is_exact(&self) -> bool {
        *self == Self::EXACT
    }
}

impl Default for ArmError {
    fn default() -> Self {
        Self::EXACT
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_draw_within_their_bounds_and_repeat_by_seed() {
        assert_eq!(ArmError::draw(0, 7), Some(ArmError::EXACT));
        assert_eq!(ArmError::draw(3, 7), None);
        for level in 1..=2u8 {
            let b = ArmError::LEVELS[level as usize];
            for seed in 0..50 {
                let e = ArmError::draw(level, seed).unwrap();
                assert_eq!(ArmError::draw(level, seed), Some(e));
                assert!(!e.is_exact());
                assert!(e.zero_rad.iter().all(|z| z.abs() <= b.deg.to_radians() + 1e-12), "{e:?}");
                assert!(e.length.iter().all(|l| (l - 1.0).abs() <= b.share + 1e-12), "{e:?}");
            }
            assert_ne!(ArmError::draw(level, 1), ArmError::draw(level, 2));
        }
    }
}
