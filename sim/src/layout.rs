//! The on-disk dataset layout, shared by `msr dataset` (which writes it) and every command that
//! reads a dataset. Modelled on the published real data (`manifest.json` there):
//!
//! ```text
//! DIR/dataset.json        this index (DatasetIndex)
//! DIR/head_angles.csv     one "HeadYaw,HeadPitch" row per frame, radians, no header (as published)
//! DIR/template.png        the robot's face template for the crop (grey)
//! DIR/frames/000000.png   320 x 240 camera frames (RGB), the mirror view
//! DIR/masks/000123.png    for marked frames: the mark's pixel mask (full frame, 0 or 255)
//! DIR/reach_centroids.csv reach training inputs: one "x,y" row per pair, the mark's position in
//!                         full-frame pixels at head (0, 0), rounded (as the published
//!                         centroid_samples.csv); optional
//! DIR/reach_joints.csv    reach training targets, row for row: "HeadYaw,HeadPitch,LShoulderPitch,
//!                         LShoulderRoll,LElbowRoll" in radians that touch that mark (made by the
//!                         sim's IK; as the published arm_samples.csv); optional
//! ```
use serde::{Deserialize, Serialize};

/// The dataset's index file.
pub const INDEX_FILE: &str = "dataset.json";
/// The head angles of every frame, one line a frame.
pub const ANGLES_FILE: &str = "head_angles.csv";
/// The face template used to crop.
pub const TEMPLATE_FILE: &str = "template.png";
/// Reach training pairs: the mark centroids.
pub const REACH_CENTROIDS_FILE: &str = "reach_centroids.csv";
/// Reach training pairs: the joint angles.
pub const REACH_JOINTS_FILE: &str = "reach_joints.csv";

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
/// Which split a frame belongs to.
pub enum Split {
    /// The training split.
    Train,
    /// The test split.
    Test,
}

/// A mark's exact ground truth.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MarkRecord {
    /// e.g. "rectangle", "hexagon", "postit", "vbar", "hbar".
    pub shape: String,
    /// Colour name, e.g. "green".
    pub colour: String,
    /// Colour, RGB.
    pub rgb: [u8; 3],
    /// Inclusive box in full-frame pixels: [x0, y0, x1, y1].
    pub box_xyxy_inclusive: [u32; 4],
    /// Number of mark pixels in the frame.
    pub pixels: u32,
    /// Path of the mask PNG, relative to the dataset folder.
    pub mask: String,
    /// The mark's centre on the head surface, in the head frame (metres).
    pub point_head_m: [f64; 3],
    /// The same point in the torso frame at this frame's head angles (metres); in the other
    /// scene, the other robot's torso frame at its head angles (`seen_head`).
    pub point_torso_m: [f64; 3],
}

/// One frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameRecord {
    /// Path of the frame PNG, relative to the dataset folder.
    pub file: String,
    /// HeadYaw the frame was taken at, radians.
    pub head_yaw: f64,
    /// HeadPitch the frame was taken at, radians.
    pub head_pitch: f64,
    /// The split the frame is in.
    pub split: Split,
    /// The mark on the face, if any.
    pub mark: Option<MarkRecord>,
    /// Another robot's head (yaw, pitch) when the frame shows another robot, not the mirror
    /// image (`msr dataset --scene other`); absent for the own mirror image.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seen_head: Option<[f64; 2]>,
}

/// `dataset.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DatasetIndex {
    /// "red" or "skin" for sim datasets; free text for recordings.
    pub robot: String,
    /// Seed the dataset was drawn with.
    pub seed: u64,
    /// Frame width, pixels.
    pub width: u32,
    /// Frame height, pixels.
    pub height: u32,
    /// Path of the face template, relative to the dataset folder.
    pub template: String,
    /// Every frame, in file order.
    pub frames: Vec<FrameRecord>,
    /// The V4L2 camera controls a recording was held at (`msr record --camera`), by name
    /// (`exposure_absolute`, `gain`, `white_balance_temperature`); absent for other datasets.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_controls: Option<std::collections::BTreeMap<String, i32>>,
    /// The camera imperfections the frames were rendered through (`msr dataset` with a camera
    /// flag, `msr record --sim`); absent when none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub imperfections: Option<crate::imperfect::Imperfections>,
}

impl DatasetIndex {
    /// The frames of split `s`, with their indices.
    pub fn split(&self, s: Split) -> impl Iterator<Item = (usize, &FrameRecord)> {
        self.frames.iter().enumerate().filter(move |(_, f)| f.split == s)
    }
}
