//! The camera's imperfections as flags (`msr_sim::imperfect::Imperfections`): one definition for
//! the commands that render sim frames (`msr dataset`, `msr mirror-test`, `msr run --sim`,
//! `msr record --sim`) and those that take test frames (`msr eval`, `msr detect`); one range check
//! (in [`super::check`]), in the unit each flag names.
use msr_sim::imperfect::Imperfections;

#[derive(clap::Args, Debug, Clone)]
pub struct CameraFlags {
    /// Camera: exposure factor (0.05..=20), on the colour frame before grey (clipped at 255)
    #[arg(long, default_value_t = 1.0)]
    pub exposure: f64,
    /// Camera: tone curve 255 (v/255)^GAMMA (0.2..=5; under 1 brightens the mid-tones)
    #[arg(long, default_value_t = 1.0)]
    pub gamma: f64,
    /// Camera: the colour temperature of the light, K (2000..=12000), against a white balance
    /// set for 5500 K: lower is warmer (green and blue down), higher cooler
    #[arg(long, alias = "color-temperature", default_value_t = 5500.0)]
    pub colour_temperature: f64,
    /// Camera: white balance as gains R,G,B (each 0.25..=4), e.g. 1.15,1,0.85 for a camera
    /// balanced 15 % warm; in place of --colour-temperature
    #[arg(long, value_name = "R,G,B", value_delimiter = ',', conflicts_with = "colour_temperature")]
    pub white_balance: Vec<f64>,
    /// Camera: sensor noise, grey levels sd (0..=64), Gaussian, the same draws on every run
    #[arg(long, default_value_t = 0.0)]
    pub noise: f64,
    /// Camera: defocus, the Gaussian blur's sigma in px (0..=10)
    #[arg(long, default_value_t = 0.0)]
    pub defocus: f64,
    /// Camera: motion blur, px (0..=50) along --motion-angle; in episodes and `--sim` streams,
    /// the smear at the head's default speed (0.83 rad/s), scaled by its speed between frames
    /// and along its direction (a head at rest takes sharp frames)
    #[arg(long, default_value_t = 0.0)]
    pub motion_blur: f64,
    /// Camera: direction of --motion-blur in the image, degrees (0: horizontal, 90: vertical)
    #[arg(long, default_value_t = 0.0)]
    pub motion_angle: f64,
    /// Camera: JPEG quality the frames go through (1..=100), as an MJPEG webcam streams them
    #[arg(long)]
    pub jpeg: Option<i64>,
}

impl CameraFlags {
    /// The imperfections these flags ask for, the noise drawn from `seed` (checked ranges:
    /// [`super::check`]).
    pub fn imperfections(&self, seed: u64) -> Imperfections {
        Imperfections::NONE
            .with_exposure(self.exposure as f32)
            .with_gamma(self.gamma as f32)
            .with_colour_temperature(self.colour_temperature as f32)
            .with_white_balance(match self.white_balance[..] {
                [r, g, b] => [r as f32, g as f32, b as f32],
                _ => msr_sim::light::tint_of_kelvin(self.colour_temperature as f32),
            })
            .with_noise(self.noise as f32)
            .with_defocus(self.defocus as f32)
            .with_motion(self.motion_blur as f32, self.motion_angle as f32)
            .with_jpeg(self.jpeg.map(|q| q.clamp(1, 100) as u8))
            .with_seed(seed)
    }
}
