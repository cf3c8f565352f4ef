//! The ways a [`TrainConfig`](super::TrainConfig) can be wrong for its dataset, as a typed error.
//!
//! The library names the configuration's fields; the command line, which knows the flags, says
//! the same with the flags' names (the command shells walk an error's causes for this type).
use std::fmt;
use std::path::PathBuf;

/// A training configuration that cannot train, found before any training.
#[derive(Debug, Clone, PartialEq)]
pub enum ConfigError {
    /// `min_area` is 0: a blob needs at least one pixel.
    MinArea,
    /// `threshold_percentile` outside 0..=100.
    Percentile(f64),
    /// `pose_bins` is neither 0 (off) nor in 2..=`most`.
    PoseBins {
        /// The cells per angle asked for.
        got: u8,
        /// The most cells per angle the blob holds.
        most: u8,
    },
    /// `conv_hidden` or `conv_channels` given for the dense (MLP) architecture.
    ConvSizesWithoutConv,
    /// `threshold_percentile` is set but the test split has no unmarked frame to take it from.
    NoNormalTestFrames {
        /// The dataset folder.
        data: PathBuf,
    },
    /// A head-pose cell has fewer than 2 unmarked training frames (a standard deviation needs 2).
    FewFramesPerPoseCell {
        /// The cells per angle asked for.
        pose_bins: u8,
        /// The default cells per angle, named in the message.
        default: u8,
        /// Cells in the grid (`pose_bins` squared).
        cells: usize,
        /// The dataset folder.
        data: PathBuf,
        /// Unmarked training frames in the emptiest cell.
        fewest: usize,
        /// Unmarked training frames in all cells.
        total: usize,
    },
    /// The light copies' gradient is not within 0..0.5 (a share of the grey level).
    LightGradient(f32),
    /// The light copies' gamma is not within 0..0.5.
    LightGamma(f32),
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::MinArea => f.write_str("min_area must be at least 1"),
            Self::Percentile(p) => write!(f, "threshold_percentile must be within 0..=100, got {p}"),
            Self::PoseBins { got, most } => write!(f, "pose_bins must be 0 (off) or 2..={most}, got {got}"),
            Self::ConvSizesWithoutConv => f.write_str("conv_hidden and conv_channels are for ArchKind::Conv"),
            Self::NoNormalTestFrames { data } => write!(
                f,
                "threshold_percentile needs normal held-out frames, but the test split of {} has no unmarked frame",
                data.display()
            ),
            Self::FewFramesPerPoseCell { pose_bins, default, cells, data, fewest, total } => write!(
                f,
                "pose_bins {pose_bins} (the default is {default}) needs at least 2 unmarked training frames in each \
                 of the {cells} head-pose cells, but dataset {} has {fewest} in one ({total} in all); set pose_bins \
                 to 0 (one set of statistics for all poses) or fewer cells, or render more frames",
                data.display()
            ),
            Self::LightGradient(g) => write!(f, "light_gradient must be in 0..0.5 (a share of the grey level), got {g}"),
            Self::LightGamma(g) => write!(f, "light_gamma must be in 0..0.5, got {g}"),
        }
    }
}

impl std::error::Error for ConfigError {}
