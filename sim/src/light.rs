//! Light in the mirror world: the room's lamps, the camera's exposure and white balance, and a
//! camera that runs its own auto-exposure loop.
//!
//! [`Light::FIXED`] is the light every frame had before light became part of the world; a
//! render with it gives the same bytes as before (tested in `render::tests`). Datasets draw a
//! light per frame ([`LightMode::Varied`]); trials follow a [`LightPlan`] over simulated time.
use nalgebra::Vector3;
use rand::Rng;

/// The light of one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Light {
    /// Exposure factor of the camera (1 = the calibrated exposure), on top of the camera's
    /// per-frame jitter (`Variation::exposure`).
    pub exposure: f32,
    /// Strength of the key lamp (1 = the calibrated one): its diffuse and specular light.
    pub key: f32,
    /// Where the key lamp shines from (torso frame, unnormalised).
    pub key_dir: [f64; 3],
    /// Share of light that reaches every surface (`looks::AMBIENT` = 0.45 calibrated).
    pub ambient: f32,
    /// White-balance error per channel (R, G, B multipliers; 1 = balanced), from a colour
    /// temperature by [`tint_of_kelvin`].
    pub tint: [f32; 3],
}

impl Light {
    /// The calibrated light: today's frames.
    pub const FIXED: Light = Light {
        exposure: 1.0,
        key: 1.0,
        // `looks::LIGHT` (a test checks they agree).
        key_dir: [1.0, 0.35, 0.9],
        ambient: crate::looks::AMBIENT,
        tint: [1.0; 3],
    };

    /// Direction of the key lamp, as a vector.
    pub fn key_dir(&self) -> Vector3<f64> {
        Vector3::new(self.key_dir[0], self.key_dir[1], self.key_dir[2])
    }

    /// How bright the room's walls are against the calibrated light (the background is lit by
    /// the ambient light and the lamp in equal parts); exactly 1 for [`Light::FIXED`].
    pub fn room(&self) -> f32 {
        0.5 * (self.ambient / crate::looks::AMBIENT) + 0.5 * self.key
    }

    /// A light drawn for one training or test frame of a varied-light dataset: exposure within
    /// +-30 %, the key lamp at 0.55..1.45 of its strength (a lamp switched on or off) and turned
    /// by up to about 6 degrees, ambient share 0.4..0.5, colour temperature 5000..6500 K against
    /// a camera balanced for 5500 K. (Wider ranges, a lamp turned by 25 degrees, ambient
    /// 0.3..0.6 and 4000..8000 K, left shading that no gain and offset take back, and the error
    /// statistics measured over them lost half the red robot's marks.)
    pub fn varied<R: Rng>(rng: &mut R) -> Light {
        let d = crate::looks::LIGHT;
        Light {
            exposure: rng.gen_range(0.7..1.3),
            key: rng.gen_range(0.55..1.45),
            key_dir: [d.x, d.y + rng.gen_range(-0.1..0.1), d.z + rng.gen_range(-0.1..0.1)],
            ambient: rng.gen_range(0.4..0.5),
            tint: tint_of_kelvin(rng.gen_range(5000.0..6500.0)),
        }
    }

    /// The fixed light with a lamp switched on or off: the key lamp 25..45 % stronger or
    /// weaker (what [`LightPlan::Step`] switches to).
    pub fn lamp<R: Rng>(rng: &mut R) -> Light {
        let d = if rng.gen_bool(0.5) { 1.0 } else { -1.0 };
        Light { key: 1.0 + d * rng.gen_range(0.25..0.45), ..Light::FIXED }
    }

    /// The fixed light with the key lamp turned to the edge of [`Light::varied`]'s range: its
    /// direction moved by 0.1 along each of two axes, either way (4.2 to 5.7 degrees).
    pub fn turned<R: Rng>(rng: &mut R) -> Light {
        let d = crate::looks::LIGHT;
        let mut side = || if rng.gen_bool(0.5) { 0.1 } else { -0.1 };
        Light { key_dir: [d.x, d.y + side(), d.z + side()], ..Light::FIXED }
    }

    /// The fixed light with the ambient share at an end of [`Light::varied`]'s range: 0.40 or
    /// 0.50 (calibrated 0.45).
    pub fn ambient<R: Rng>(rng: &mut R) -> Light {
        Light { ambient: if rng.gen_bool(0.5) { 0.4 } else { 0.5 }, ..Light::FIXED }
    }

    /// The fixed light at an end of [`Light::varied`]'s colour temperatures: 5000 or 6500 K,
    /// against a camera balanced for 5500 K.
    pub fn colour<R: Rng>(rng: &mut R) -> Light {
        Light { tint: tint_of_kelvin(if rng.gen_bool(0.5) { 5000.0 } else { 6500.0 }), ..Light::FIXED }
    }

    /// This light with the exposure multiplied by `k`.
    pub fn exposed(self, k: f32) -> Light {
        Light { exposure: self.exposure * k, ..self }
    }
}

/// RGB of a black body at `kelvin` (Tanner Helland's fit), over that of 5500 K: what a camera
/// white-balanced for 5500 K records of a grey surface. Green is about 1 over the range.
pub fn tint_of_kelvin(kelvin: f32) -> [f32; 3] {
    let rgb = |k: f32| -> [f32; 3] {
        let t = k / 100.0;
        let r = if t <= 66.0 { 255.0 } else { 329.699 * (t - 60.0).powf(-0.133_204_76) };
        let g = if t <= 66.0 { 99.470_8 * t.ln() - 161.119_57 } else { 288.122_17 * (t - 60.0).powf(-0.075_514_85) };
        let b = if t >= 66.0 {
            255.0
        } else if t <= 19.0 {
            0.0
        } else {
            138.517_73 * (t - 10.0).ln() - 305.044_8
        };
        [r, g, b].map(|c| c.clamp(1.0, 255.0))
    };
    let (a, z) = (rgb(kelvin), rgb(5500.0));
    [a[0] / z[0], a[1] / z[1], a[2] / z[2]]
}

/// How a dataset's frames are lit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LightMode {
    /// [`Light::FIXED`]: the same bytes as before light was part of the world.
    #[default]
    Fixed,
    /// A light of its own per frame ([`Light::varied`]).
    Varied,
    /// Half the training split varied (a coin per frame), the rest and the test split under the
    /// fixed light: the statistics cover many lights while the decoder still learns the face
    /// from the calibrated one (every frame varied left the red robot at 0.93 of its marks, half
    /// at 0.97); evaluated on the calibrated light (which `msr eval --exposure` scales).
    VariedTrain,
    /// Every frame with a lamp switched on or off against the fixed light ([`Light::lamp`]).
    Lamp,
    /// Every frame with the key lamp turned ([`Light::turned`]), nothing else changed.
    Turn,
    /// Every frame with another ambient share ([`Light::ambient`]), nothing else changed.
    Ambient,
    /// Every frame at another colour temperature ([`Light::colour`]), nothing else changed.
    Colour,
}

impl LightMode {
    /// The mode's name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            LightMode::Fixed => "fixed",
            LightMode::Varied => "varied",
            LightMode::VariedTrain => "varied-train",
            LightMode::Lamp => "lamp",
            LightMode::Turn => "turn",
            LightMode::Ambient => "ambient",
            LightMode::Colour => "colour",
        }
    }

    /// The light of a frame of the training split (`train`) or the test split, drawn from `rng`
    /// (`None`: [`Light::FIXED`], nothing drawn).
    pub fn draw<R: Rng>(self, train: bool, rng: &mut R) -> Option<Light> {
        match (self, train) {
            (LightMode::Fixed, _) | (LightMode::VariedTrain, false) => None,
            (LightMode::Varied, _) => Some(Light::varied(rng)),
            (LightMode::VariedTrain, true) => rng.gen_bool(0.5).then(|| Light::varied(rng)),
            (LightMode::Lamp, _) => Some(Light::lamp(rng)),
            (LightMode::Turn, _) => Some(Light::turned(rng)),
            (LightMode::Ambient, _) => Some(Light::ambient(rng)),
            (LightMode::Colour, _) => Some(Light::colour(rng)),
        }
    }
}

/// How the light changes over a trial (a stream of frames in simulated time).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LightPlan {
    /// [`Light::FIXED`] throughout.
    #[default]
    Fixed,
    /// The exposure ramps from 1 to 1 + d, d drawn within +-30 %, over the trial.
    Drift,
    /// A lamp switches on or off at a random moment of the trial: the key lamp's strength jumps
    /// by 25..45 % up or down.
    Step,
    /// The room is 0.65..1.5 times as bright as calibrated (drawn per trial: every lamp alike,
    /// the shading as calibrated); the camera's own gain loop ([`AutoExposure`]) brings the
    /// picture back, with a lag, and moves when the arm enters the view.
    AutoExposure,
    /// Slowly, over the whole schedule: the key lamp turns by 8..12 degrees about the vertical,
    /// the light warms to 4500..5000 K or cools to 6500..7000 K, and the ambient share falls
    /// from 0.45 to 0.40. Shading that no per-frame gain and offset take back; meant for a long
    /// run on one board (`msr mirror-test --one-board`), where the board learns the room.
    Turn,
}

impl LightPlan {
    /// The plan's name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            LightPlan::Fixed => "fixed",
            LightPlan::Drift => "drift",
            LightPlan::Step => "step",
            LightPlan::AutoExposure => "auto-exposure",
            LightPlan::Turn => "turn",
        }
    }
}

/// A [`LightPlan`] drawn for one trial of `duration_us`: the light at any moment, and the camera
/// gain loop when the plan has one.
#[derive(Clone, Debug, PartialEq)]
pub struct LightSchedule {
    /// The plan drawn.
    pub plan: LightPlan,
    duration_us: u64,
    /// Drift: the exposure's change at the end. Step: the key lamp's factor after the switch.
    /// Auto-exposure: the room's brightness. Turn: the lamp's turn at the end, radians.
    amount: f32,
    /// Turn: the colour temperature at the end, K.
    kelvin: f32,
    /// Step: when the lamp switches.
    at_us: u64,
    /// The camera's gain loop ([`LightPlan::AutoExposure`] only).
    pub auto: Option<AutoExposure>,
}

impl LightSchedule {
    /// Draws the plan's random parts for one trial.
    pub fn new<R: Rng>(plan: LightPlan, duration_us: u64, rng: &mut R) -> LightSchedule {
        let sign = |rng: &mut R| if rng.gen_bool(0.5) { 1.0 } else { -1.0 };
        let (amount, at_us, auto) = match plan {
            LightPlan::Fixed => (0.0, 0, None),
            LightPlan::Drift => (sign(rng) * rng.gen_range(0.1..0.3), 0, None),
            LightPlan::Step => {
                let at = rng.gen_range(0..duration_us.max(1));
                (1.0 + sign(rng) * rng.gen_range(0.25..0.45), at, None)
            }
            LightPlan::AutoExposure => (rng.gen_range(0.65..1.5), 0, Some(AutoExposure::new())),
            LightPlan::Turn => (sign(rng) * rng.gen_range(8f32..12.0).to_radians(), 0, None),
        };
        let kelvin = match plan {
            LightPlan::Turn if rng.gen_bool(0.5) => rng.gen_range(4500.0..5000.0),
            LightPlan::Turn => rng.gen_range(6500.0..7000.0),
            _ => 5500.0,
        };
        LightSchedule { plan, duration_us: duration_us.max(1), amount, kelvin, at_us, auto }
    }

    /// The light of a frame taken at `now_us` (before the camera's own gain).
    pub fn at(&self, now_us: u64) -> Light {
        let f = Light::FIXED;
        match self.plan {
            LightPlan::Fixed => f,
            LightPlan::Drift => {
                let s = (now_us.min(self.duration_us) as f64 / self.duration_us as f64) as f32;
                f.exposed(1.0 + self.amount * s)
            }
            LightPlan::Step => {
                if now_us >= self.at_us { Light { key: self.amount, ..f } } else { f }
            }
            LightPlan::AutoExposure => {
                // Every lamp of the room `amount` times as bright: the light on the face scales
                // as a whole, its shading stays. (Until 2026-12-03 the ambient *share* was
                // scaled with the room, 0.29..0.68, which also shrank the key lamp's part:
                // a shading change no exposure makes, outside what varied-light statistics
                // cover; the red robot reached for its unmarked face in 14 of 200 trials.)
                let gain = self.auto.as_ref().map_or(1.0, |a| a.gain);
                f.exposed(self.amount * gain)
            }
            LightPlan::Turn => {
                let s = (now_us.min(self.duration_us) as f64 / self.duration_us as f64) as f32;
                let (sin, cos) = ((self.amount * s) as f64).sin_cos();
                let [x, y, z] = f.key_dir;
                Light {
                    key_dir: [x * cos - y * sin, x * sin + y * cos, z],
                    ambient: f.ambient - 0.05 * s,
                    tint: tint_of_kelvin(5500.0 + (self.kelvin - 5500.0) * s),
                    ..f
                }
            }
        }
    }

    /// Tells the gain loop (if any) what the camera just saw.
    pub fn observed(&mut self, rgb: &image::RgbImage) {
        if let Some(a) = self.auto.as_mut() {
            a.update(mean_grey(rgb.as_raw(), 3, rgb.width()));
        }
    }

    /// As [`LightSchedule::observed`], for a grey frame.
    pub fn observed_grey(&mut self, grey: &image::GrayImage) {
        if let Some(a) = self.auto.as_mut() {
            a.update(mean_grey(grey.as_raw(), 1, grey.width()));
        }
    }
}

/// A camera's auto-exposure: the gain follows the frame's mean brightness towards a target,
/// a share of the way each frame (a first-order lag), within limits.
#[derive(Clone, Debug, PartialEq)]
pub struct AutoExposure {
    /// The gain now.
    pub gain: f32,
    /// Mean grey (0..255) the loop aims for: the calibrated scene's.
    pub target: f32,
    /// Share of the correction made per frame.
    pub rate: f32,
}

impl AutoExposure {
    /// Mean grey of the calibrated mirror view at home (both robots: 190..200).
    pub const TARGET: f32 = 196.0;

    /// The loop at gain 1, aiming at [`AutoExposure::TARGET`].
    pub fn new() -> AutoExposure {
        AutoExposure { gain: 1.0, target: Self::TARGET, rate: 0.15 }
    }

    /// One step of the loop after a frame whose mean grey was `mean`.
    pub fn update(&mut self, mean: f32) {
        let mean = mean.max(1.0);
        let wanted = self.gain * self.target / mean;
        self.gain = (self.gain + self.rate * (wanted - self.gain)).clamp(0.25, 4.0);
    }
}

/// Mean grey (0..255) over every 4th pixel of every 4th row of an image of `channels` bytes
/// a pixel (RGB with the grey weights), `w` pixels wide.
pub fn mean_grey(raw: &[u8], channels: usize, w: u32) -> f32 {
    let w = w as usize;
    if w == 0 || channels == 0 {
        return 0.0;
    }
    let (mut sum, mut n) = (0f64, 0u32);
    for row in raw.chunks_exact(w * channels).step_by(4) {
        for p in row.chunks_exact(channels).step_by(4) {
            sum += match p {
                [r, g, b] => 0.299 * *r as f64 + 0.587 * *g as f64 + 0.114 * *b as f64,
                _ => p[0] as f64,
            };
            n += 1;
        }
    }
    if n == 0 { 0.0 } else { (sum / n as f64) as f32 }
}

impl Default for AutoExposure {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn a_balanced_camera_sees_no_tint_and_warm_light_is_red() {
        let t = tint_of_kelvin(5500.0);
        assert!(t.iter().all(|&c| (c - 1.0).abs() < 1e-6), "{t:?}");
        let warm = tint_of_kelvin(4000.0);
        assert!(warm[0] > warm[1] && warm[1] > warm[2] && warm[2] < 0.8, "{warm:?}");
        let cold = tint_of_kelvin(8000.0);
        assert!(cold[0] < 0.95 && cold[2] > 1.0, "{cold:?}");
    }

    /// Each single-nuisance light changes its own part of the fixed light and nothing else,
    /// by what its doc says.
    #[test]
    fn one_nuisance_at_a_time() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (mut warm, mut cold) = (0, 0);
        for _ in 0..64 {
            let t = Light::turned(&mut rng);
            assert_eq!(Light { key_dir: Light::FIXED.key_dir, ..t }, Light::FIXED);
            let deg = t.key_dir().angle(&Light::FIXED.key_dir()).to_degrees();
            assert!((4.2..=5.75).contains(&deg), "{deg}");
            let a = Light::ambient(&mut rng);
            assert_eq!(Light { ambient: Light::FIXED.ambient, ..a }, Light::FIXED);
            assert!(a.ambient == 0.4 || a.ambient == 0.5, "{}", a.ambient);
            let c = Light::colour(&mut rng);
            assert_eq!(Light { tint: Light::FIXED.tint, ..c }, Light::FIXED);
            if c.tint[2] < 1.0 { warm += 1 } else { cold += 1 }
        }
        assert!(warm > 10 && cold > 10, "{warm} {cold}");
        assert_eq!(LightMode::Turn.draw(false, &mut rng).map(|l| l.key), Some(1.0));
    }

    #[test]
    fn the_fixed_key_lamp_is_the_looks_one() {
        assert_eq!(Light::FIXED.key_dir(), crate::looks::LIGHT);
        assert_eq!(Light::FIXED.room(), 1.0);
    }

    #[test]
    fn plans_give_the_light_they_promise() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let d = LightSchedule::new(LightPlan::Drift, 1000, &mut rng);
        assert_eq!(d.at(0), Light::FIXED);
        let end = d.at(1000).exposure;
        assert!((0.7..=1.3).contains(&end) && (end - 1.0).abs() >= 0.1, "{end}");
        let s = LightSchedule::new(LightPlan::Step, 1000, &mut rng);
        assert_eq!(s.at(0).key, 1.0);
        let k = s.at(1000).key;
        assert!((0.55..=0.75).contains(&k) || (1.25..=1.45).contains(&k), "{k}");
        assert_eq!(LightSchedule::new(LightPlan::Fixed, 10, &mut rng).at(5), Light::FIXED);
        // Auto-exposure: the room brighter or darker as a whole (the shading as calibrated),
        // times the camera's gain, which follows what it saw.
        let mut a = LightSchedule::new(LightPlan::AutoExposure, 1000, &mut rng);
        let room = a.at(0).exposure;
        assert!((0.65..=1.5).contains(&room), "{room}");
        assert_eq!(a.at(0), Light::FIXED.exposed(room));
        a.observed_grey(&image::GrayImage::from_pixel(8, 8, image::Luma([250])));
        let l = a.at(0);
        assert!(l.exposure < room, "a bright picture turns the gain down");
        assert_eq!((l.key, l.ambient, l.key_dir, l.tint), (1.0, Light::FIXED.ambient, Light::FIXED.key_dir, [1.0; 3]));
        assert_eq!(l.room(), 1.0, "the walls are lit as the face: exposure only");
    }

    #[test]
    fn the_gain_loop_follows_a_dark_picture_with_a_lag() {
        let mut a = AutoExposure::new();
        let dark = image::RgbImage::from_pixel(32, 24, image::Rgb([98, 98, 98]));
        a.update(mean_grey(dark.as_raw(), 3, 32));
        // Half the target: the gain wants 2, moves 15 % of the way.
        assert!((a.gain - 1.15).abs() < 1e-3, "{}", a.gain);
        for _ in 0..60 {
            a.update(98.0 * a.gain);
        }
        assert!((a.gain - 2.0).abs() < 0.05, "{}", a.gain);
    }
}
