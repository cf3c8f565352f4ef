//! `--light` on the commands that render sim frames: the command-line names of the sim's light
//! settings (`msr_sim::light`).
use msr_sim::light::{LightMode, LightPlan};

/// How a dataset's frames are lit.
#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DatasetLight {
    /// The calibrated light on every frame
    #[default]
    Fixed,
    /// A light of its own per frame: exposure +-30 %, key lamp 0.55..1.45 and turned a little,
    /// ambient 0.4..0.5, colour temperature 5000..6500 K
    Varied,
    /// Half the training split varied, the test split fixed (what `msr demo` trains on)
    VariedTrain,
    /// Every frame with a lamp switched on or off (the key lamp 25..45 % stronger or weaker)
    Lamp,
    /// One nuisance: the key lamp turned by 4.2..5.7 degrees (the edge of varied's range)
    Turn,
    /// One nuisance: the ambient share at 0.40 or 0.50 (calibrated 0.45)
    Ambient,
    /// One nuisance: the colour temperature at 5000 or 6500 K (the camera balanced for 5500 K)
    Colour,
}

impl From<DatasetLight> for LightMode {
    fn from(l: DatasetLight) -> LightMode {
        match l {
            DatasetLight::Fixed => LightMode::Fixed,
            DatasetLight::Varied => LightMode::Varied,
            DatasetLight::VariedTrain => LightMode::VariedTrain,
            DatasetLight::Lamp => LightMode::Lamp,
            DatasetLight::Turn => LightMode::Turn,
            DatasetLight::Ambient => LightMode::Ambient,
            DatasetLight::Colour => LightMode::Colour,
        }
    }
}

/// How the light changes over a run of frames.
#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum RunLight {
    /// The calibrated light throughout
    #[default]
    Fixed,
    /// The exposure ramps by 10..30 % up or down over the trial
    Drift,
    /// A lamp switches on or off at a random moment: the key light jumps by 25..45 %
    Step,
    /// The room 0.65..1.5 times as bright; the camera's own gain loop follows with a lag
    AutoExposure,
    /// Slowly over the whole run: the lamp turns by 8..12 degrees, the light warms or cools by
    /// 500..1500 K, the ambient share falls by a ninth (for --one-board)
    Turn,
}

impl From<RunLight> for LightPlan {
    fn from(l: RunLight) -> LightPlan {
        match l {
            RunLight::Fixed => LightPlan::Fixed,
            RunLight::Drift => LightPlan::Drift,
            RunLight::Step => LightPlan::Step,
            RunLight::AutoExposure => LightPlan::AutoExposure,
            RunLight::Turn => LightPlan::Turn,
        }
    }
}
