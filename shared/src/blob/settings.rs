//! What the board decides with: novelty settings, the pose region and grid, the self gate.

use super::{
    MAX_MERGE_MARGIN, MAX_GATE_AMPLITUDE, MAX_GATE_TIMEOUT_MS, MAX_GATE_FRAMES, MAX_POSE_BINS,
    MAX_POSE_ANGLE, MAX_REGION_RADIUS,
};
use serde::{Deserialize, Serialize};
use super::view::U16Table;

/// How the prediction error is normalised before the threshold.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Normalisation {
    /// `(e - mu) / sigma`, as the published code.
    StdDev,
    /// `(e - mu) / sigma^2`, as the paper's text.
    Variance,
}

/// Whether only errors above the mean count, or both directions.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Sided {
    /// `(e - mu) / n > t`.
    One,
    /// `|e - mu| / n > t`, as the published code.
    Two,
}

/// Novelty detection parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Novelty {
    /// Saliency threshold, in units of the normalisation (finite, > 0).
    pub threshold: f32,
    /// Whether the error is divided by sigma or sigma^2.
    pub normalisation: Normalisation,
    /// One- or two-sided test.
    pub sided: Sided,
    /// Smallest blob, pixels, that counts as a mark (>= 1).
    pub min_area: u16,
    /// The floor applied to sigma when the statistics were made (grey levels), for reference.
    pub sigma_floor: f32,
    /// Fragment merge before the `min_area` test; [`Merge::OFF`] for the paper's blob stage.
    pub merge: Merge,
    /// Radius of the window the signed error is averaged over before its magnitude is taken
    /// (flag bit 4); 0: per pixel, the paper's error.
    pub pool: u8,
    /// The spread of the error over the frames the statistics came from, grey levels (flag
    /// bit 6): each frame's sigma is widened by what its own error spreads beyond it (the
    /// firmware's `floor`). `None`: the statistics alone, as before.
    pub spread_ref: Option<f32>,
}

/// Merging of nearby components before the minimum-area test (a deviation from the paper, for
/// marks that the saliency breaks up, e.g. along a textured cover). `margin` 0: off.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Merge {
    /// Two boxes merge when one, grown by this many pixels on every side, overlaps the other
    /// (so at most `margin - 1` empty rows or columns lie between them).
    pub margin: u8,
    /// Smallest component (pixels) that takes part; smaller ones are dropped as noise.
    pub fragment: u16,
}

impl Merge {
    /// The paper's blob stage: no merge.
    pub const OFF: Merge = Merge { margin: 0, fragment: 0 };

    /// `margin` > 0.
    pub fn is_on(&self) -> bool {
        self.margin > 0
    }

    /// Off, or a margin up to [`MAX_MERGE_MARGIN`] with `1 <= fragment <= min_area`.
    pub fn is_valid(&self, min_area: u16) -> bool {
        if self.margin == 0 {
            self.fragment == 0
        } else {
            self.margin <= MAX_MERGE_MARGIN && self.fragment >= 1 && self.fragment <= min_area
        }
    }
}

/// Novelty settings that replace the model's own for head poses near `centre`: a threshold and
/// merge calibrated at the pose where the robot looks for marks (its observe posture), while
/// the model's own settings hold for every other pose. `threshold` is in the model's
/// normalisation, like [`Novelty::threshold`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseRegion {
    /// `[HeadYaw, HeadPitch]`, radians.
    pub centre: [f32; 2],
    /// Radians, in the (yaw, pitch) plane.
    pub radius: f32,
    /// Threshold used inside the region, in the model's normalisation (finite, > 0).
    pub threshold: f32,
    /// Fragment merge used inside the region.
    pub merge: Merge,
}

impl PoseRegion {
    /// Whether `head` lies within `radius` of the centre (not for non-finite angles).
    pub fn contains(&self, head: [f32; 2]) -> bool {
        let (dy, dp) = (head[0] - self.centre[0], head[1] - self.centre[1]);
        dy * dy + dp * dp <= self.radius * self.radius
    }

    /// Finite centre, `0 < radius <= MAX_REGION_RADIUS`, finite positive threshold, a merge valid
    /// for `min_area`.
    pub fn is_valid(&self, min_area: u16) -> bool {
        self.centre.iter().all(|a| a.is_finite())
            && self.radius > 0.0
            && self.radius <= MAX_REGION_RADIUS
            && self.threshold.is_finite()
            && self.threshold > 0.0
            && self.merge.is_valid(min_area)
    }
}

/// A grid over the head pose, `bins[0]` cells of yaw from `lo[0]` to `hi[0]` by `bins[1]` of
/// pitch from `lo[1]` to `hi[1]` (radians); a pose outside it counts to the nearest cell.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseGrid {
    /// Cells along yaw and pitch (each `1..=MAX_POSE_BINS`, at least 2 in all).
    pub bins: [u8; 2],
    /// Lower edges, `[yaw, pitch]`, radians.
    pub lo: [f32; 2],
    /// Upper edges, radians (`> lo`).
    pub hi: [f32; 2],
}

impl PoseGrid {
    /// Cells in all.
    pub fn len(&self) -> usize {
        self.bins[0] as usize * self.bins[1] as usize
    }

    /// Whether the grid has no cell (never for a valid one).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The cell of `head` (`pitch index x bins[0] + yaw index`), clamped to the grid; `None`
    /// for a non-finite angle. The one rule for the board and the host (f32 throughout).
    pub fn bin(&self, head: [f32; 2]) -> Option<usize> {
        let mut idx = [0usize; 2];
        for a in 0..2 {
            if !head[a].is_finite() {
                return None;
            }
            let n = self.bins[a].max(1);
            let f = (head[a] - self.lo[a]) / (self.hi[a] - self.lo[a]) * n as f32;
            // `as` saturates (negative and NaN to 0); the min clamps the top.
            idx[a] = (f as usize).min(n as usize - 1);
        }
        Some(idx[1] * self.bins[0] as usize + idx[0])
    }

    /// Cells `1..=MAX_POSE_BINS` per angle and at least 2 in all, finite edges within
    /// `MAX_POSE_ANGLE`, `lo < hi`.
    pub fn is_valid(&self) -> bool {
        self.bins.iter().all(|&b| (1..=MAX_POSE_BINS).contains(&b))
            && self.len() >= 2
            && (0..2).all(|a| {
                self.lo[a].is_finite()
                    && self.hi[a].is_finite()
                    && self.lo[a] < self.hi[a]
                    && self.lo[a].abs() <= MAX_POSE_ANGLE
                    && self.hi[a].abs() <= MAX_POSE_ANGLE
            })
    }
}

/// Error statistics per cell of a [`PoseGrid`] (flag bit 5), borrowed from the blob.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseStats<'a> {
    /// The grid.
    pub grid: PoseGrid,
    /// Every cell's mu then sigma table in turn, each `stride` bytes.
    pub(super) tables: &'a [u8],
    /// Bytes of one table with its padding.
    pub(super) stride: usize,
    /// Bytes of one table's values (2 per pixel).
    pub(super) len: usize,
}

impl<'a> PoseStats<'a> {
    /// Cell `bin`'s (mu, sigma) tables, Q8.8 grey levels; `None` past the grid.
    pub fn tables(&self, bin: usize) -> Option<(U16Table<'a>, U16Table<'a>)> {
        let at = |k: usize| {
            let start = k.checked_mul(self.stride)?;
            self.tables.get(start..start.checked_add(self.len)?).map(U16Table)
        };
        Some((at(2 * bin)?, at(2 * bin + 1)?))
    }
}

/// The self gate: before a reach, the board turns its head by `+amplitude` then `-amplitude`
/// (yaw, from where it is) and checks that the face's crop offset follows with the gain the
/// robot's own mirror image has (`firmware::self_gate`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SelfGate {
    /// Probe yaw offset, radians.
    pub amplitude: f32,
    /// Expected crop-offset x change per radian of head yaw (pixels/rad, signed).
    pub gain: f32,
    /// Largest relative error of the measured gain: `|measured / gain - 1|`.
    pub gain_tol: f32,
    /// Largest distance (pixels) of the resting face from the probe's line.
    pub rest_tol: f32,
    /// Largest x range (pixels) of the face while the head holds (at rest, at each pose).
    pub hold_tol: f32,
    /// Largest vertical move (pixels) of the face at a probe pose from its rest.
    pub level_tol: f32,
    /// With a return stage (layout 2): the probe ends back at the resting yaw the encoder
    /// reported, the poses' exact midpoint, and the face there must lie this close (pixels) to
    /// the poses' line. `None` (layouts 0 and 1): two stages, as before.
    pub line_tol: Option<f32>,
    /// With a return stage (layout 3): the most `sum((statistic / tolerance)^2)` over the gain
    /// (`|ratio - 1|` over `gain_tol`), rest, hold, level and line may reach. Each tolerance alone
    /// bounds one statistic (a box); the own image comes near one of them at a time, a stranger
    /// that gets inside the box by luck near several (`firmware::self_gate::joint`). `None`
    /// (layouts 0 to 2): the box alone.
    pub joint_tol: Option<f32>,
    /// The robot's own latency from a head pose to a frame showing it on the board, ms.
    pub latency_ms: u16,
    /// A probe not decided within this is undecided (no reach), ms.
    pub timeout_ms: u16,
    /// Frames needed at each probe pose.
    pub min_frames: u8,
}

impl SelfGate {
    /// Every field finite and in range.
    pub fn is_valid(&self) -> bool {
        self.amplitude > 0.0
            && self.amplitude <= MAX_GATE_AMPLITUDE
            && self.gain.is_finite()
            && self.gain.abs() >= 1.0
            && self.gain.abs() <= 10_000.0
            && self.gain_tol > 0.0
            && self.gain_tol < 1.0
            && [self.rest_tol, self.hold_tol, self.level_tol, self.line_tol.unwrap_or(1.0)].iter().all(|t| *t > 0.0 && *t <= 64.0)
            && self.joint_tol.is_none_or(|j| self.line_tol.is_some() && j > 0.0 && j <= 64.0)
            && (1..=1000).contains(&self.latency_ms)
            && (100..=MAX_GATE_TIMEOUT_MS).contains(&self.timeout_ms)
            && (1..=MAX_GATE_FRAMES).contains(&self.min_frames)
    }
}
