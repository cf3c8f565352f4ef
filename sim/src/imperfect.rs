//! What an ordinary camera does to a frame that the calibration camera did not: one typed,
//! seeded model ([`Imperfections`]) that the sim's camera applies to what it renders and that
//! `msr eval` and `msr detect` apply to test frames, so that every condition is one flag.
//!
//! The stages run in the order of a camera's own pipeline, each on the colour frame in floating
//! point, rounded to 8 bits once, before the frame is turned to grey:
//!
//! 1. defocus: a Gaussian blur of `defocus` px (the lens);
//! 2. motion blur: the mean along a line of `motion.length_px` px at `motion.angle_deg` (the
//!    scene moving in the image while the shutter is open; in episodes scaled by the head's
//!    angular speed, [`Imperfections::moving`]);
//! 3. exposure: every channel times `exposure` (the sensor's integration time and gain);
//! 4. sensor noise: Gaussian, `noise` grey levels, one draw a pixel on all three channels, so
//!    that the grey frame gets noise of that sd where nothing after it scales it;
//! 5. white balance: channel gains (a camera balanced for another light than the one in the
//!    room, [`Imperfections::with_colour_temperature`]);
//! 6. clip to 0..=255 (saturation), then the tone curve `255 (v / 255)^gamma`;
//! 7. rounding to 8 bits, then JPEG at `jpeg` quality (the `image` crate's coder; most USB
//!    webcams stream MJPEG).
//!
//! The default ([`Imperfections::NONE`]) changes nothing: [`Imperfections::apply`] returns the
//! frame's own bytes, so every output made without conditions stays as it was.
use image::RgbImage;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// A smear along a line, as a moving scene leaves in one exposure.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MotionBlur {
    /// Length of the smear, px (0: none).
    pub length_px: f32,
    /// Its direction in the image, degrees (0: horizontal, 90: vertical).
    pub angle_deg: f32,
}

impl MotionBlur {
    /// No motion blur.
    pub const NONE: MotionBlur = MotionBlur { length_px: 0.0, angle_deg: 0.0 };
}

/// A camera's imperfections against the calibration camera; see the module's doc for the order
/// they are applied in. Build it with `NONE` and the `with_*` methods, check it with
/// [`Imperfections::check`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Imperfections {
    /// Exposure factor (1: as calibrated), `EXPOSURE`.
    pub exposure: f32,
    /// Channel gains R, G, B of the white balance (1: balanced), each within `GAIN`.
    pub white_balance: [f32; 3],
    /// Exponent of the tone curve (1: as calibrated; under 1 brightens the mid-tones), `GAMMA`.
    pub gamma: f32,
    /// Sensor noise, grey levels sd (0: none), `NOISE`.
    pub noise: f32,
    /// Defocus, the Gaussian's sigma in px (0: sharp), `DEFOCUS`.
    pub defocus: f32,
    /// Motion blur of a still frame; in episodes, the smear at the head's default speed.
    pub motion: MotionBlur,
    /// JPEG quality 1..=100 the frame goes through (`None`: not compressed).
    pub jpeg: Option<u8>,
    /// Seed of the noise (each frame draws from it and its own number).
    pub seed: u64,
}

impl Default for Imperfections {
    fn default() -> Self {
        Imperfections::NONE
    }
}

/// What was out of range, in the library's words (the field and its range); `msr` names its
/// flags instead.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("camera {field} must be in {range}, got {got}")]
pub struct OutOfRange {
    /// The field out of range.
    pub field: &'static str,
    /// Its allowed range, as text.
    pub range: &'static str,
    /// The value given.
    pub got: String,
}

impl Imperfections {
    /// The calibration camera itself.
    pub const NONE: Imperfections = Imperfections {
        exposure: 1.0,
        white_balance: [1.0; 3],
        gamma: 1.0,
        noise: 0.0,
        defocus: 0.0,
        motion: MotionBlur::NONE,
        jpeg: None,
        seed: 0,
    };
    /// Ranges of the fields (inclusive).
    pub const EXPOSURE: (f32, f32) = (0.05, 20.0);
    /// Range of the gain.
    pub const GAIN: (f32, f32) = (0.25, 4.0);
    /// Range of the gamma.
    pub const GAMMA: (f32, f32) = (0.2, 5.0);
    /// Range of the noise, grey levels RMS.
    pub const NOISE: (f32, f32) = (0.0, 64.0);
    /// Range of the defocus blur, pixels.
    pub const DEFOCUS: (f32, f32) = (0.0, 10.0);
    /// Range of the motion blur's length, pixels.
    pub const MOTION: (f32, f32) = (0.0, 50.0);
    /// Colour temperatures `with_colour_temperature` takes, K.
    pub const KELVIN: (f32, f32) = (2000.0, 12000.0);
    /// The colour temperature the camera is balanced for, K (the sim's, `light::tint_of_kelvin`).
    pub const BALANCED_KELVIN: f32 = 5500.0;

    /// The same camera with this exposure.
    pub fn with_exposure(self, exposure: f32) -> Self {
        Imperfections { exposure, ..self }
    }
    /// The same camera with these white-balance gains (red, green, blue).
    pub fn with_white_balance(self, white_balance: [f32; 3]) -> Self {
        Imperfections { white_balance, ..self }
    }
    /// The white balance of a camera balanced for 5500 K in a light of `kelvin`
    /// ([`crate::light::tint_of_kelvin`], the sim's light's own): under 5500 warmer, over cooler.
    pub fn with_colour_temperature(self, kelvin: f32) -> Self {
        self.with_white_balance(crate::light::tint_of_kelvin(kelvin))
    }
    /// The same camera with this gamma.
    pub fn with_gamma(self, gamma: f32) -> Self {
        Imperfections { gamma, ..self }
    }
    /// The same camera with this noise.
    pub fn with_noise(self, noise: f32) -> Self {
        Imperfections { noise, ..self }
    }
    /// The same camera with this defocus blur.
    pub fn with_defocus(self, defocus: f32) -> Self {
        Imperfections { defocus, ..self }
    }
    /// The same camera with this motion blur.
    pub fn with_motion(self, length_px: f32, angle_deg: f32) -> Self {
        Imperfections { motion: MotionBlur { length_px, angle_deg }, ..self }
    }
    /// The same camera with this JPEG quality (`None`: no JPEG).
    pub fn with_jpeg(self, jpeg: Option<u8>) -> Self {
        Imperfections { jpeg, ..self }
    }
    /// The same camera with this noise seed.
    pub fn with_seed(self, seed: u64) -> Self {
        Imperfections { seed, ..self }
    }

    /// Whether this changes nothing (the seed aside).
    pub fn is_none(&self) -> bool {
        Imperfections { seed: 0, ..*self } == Imperfections::NONE
    }

    /// Every field within its range (NaN and infinities refused).
    pub fn check(&self) -> Result<(), OutOfRange> {
        let within = |field: &'static str, range: &'static str, v: f32, (lo, hi): (f32, f32)| {
            if v.is_finite() && v >= lo && v <= hi {
                Ok(())
            } else {
                Err(OutOfRange { field, range, got: v.to_string() })
            }
        };
        within("exposure", "0.05..=20", self.exposure, Self::EXPOSURE)?;
        for g in self.white_balance {
            within("white balance gain", "0.25..=4", g, Self::GAIN)?;
        }
        within("gamma", "0.2..=5", self.gamma, Self::GAMMA)?;
        within("noise", "0..=64 grey levels", self.noise, Self::NOISE)?;
        within("defocus", "0..=10 px", self.defocus, Self::DEFOCUS)?;
        within("motion blur", "0..=50 px", self.motion.length_px, Self::MOTION)?;
        within("motion blur angle", "-360..=360 degrees", self.motion.angle_deg, (-360.0, 360.0))?;
        if let Some(q) = self.jpeg {
            if !(1..=100).contains(&q) {
                return Err(OutOfRange { field: "JPEG quality", range: "1..=100", got: q.to_string() });
            }
        }
        Ok(())
    }

    /// The head's angular speed at which a frame is smeared by `motion.length_px`: the Nao's
    /// default head speed (0.1 of HeadYaw's top speed, 0.83 rad/s; about a 22 ms exposure for
    /// 5 px at the sim's focal length).
    pub fn reference_head_speed() -> f64 {
        let yaw = msr_shared::joints::Joint::HeadYaw.limits().map_or(8.26797, |l| l.max_velocity);
        (yaw * msr_shared::joints::DEFAULT_SPEED_FRACTION) as f64
    }

    /// These imperfections for a frame taken while the head turns at `head_speed` (yaw, pitch;
    /// rad/s) during the exposure: the smear `motion.length_px` scaled by the speed over
    /// [`Self::reference_head_speed`], along the image's motion (yaw moves the picture
    /// sideways, pitch up and down); a head at rest takes a sharp frame.
    pub fn moving(&self, head_speed: [f64; 2]) -> Imperfections {
        let speed = head_speed[0].hypot(head_speed[1]);
        if self.motion.length_px == 0.0 || !speed.is_finite() || speed == 0.0 {
            return Imperfections { motion: MotionBlur::NONE, ..*self };
        }
        let length = (self.motion.length_px as f64 * speed / Self::reference_head_speed()).min(Self::MOTION.1 as f64);
        let angle = head_speed[1].atan2(head_speed[0]).to_degrees();
        Imperfections { motion: MotionBlur { length_px: length as f32, angle_deg: angle as f32 }, ..*self }
    }

    /// `rgb` as this camera takes it; `frame` numbers the frame (its noise draws from the seed
    /// and it). Without imperfections, `rgb`'s own bytes.
    pub fn apply(&self, rgb: &RgbImage, frame: u64) -> RgbImage {
        if self.is_none() {
            return rgb.clone();
        }
        let (w, h) = rgb.dimensions();
        let mut f: image::Rgb32FImage =
            image::ImageBuffer::from_raw(w, h, rgb.as_raw().iter().map(|&v| v as f32).collect())
                .expect("three floats a pixel");
        if self.defocus > 0.0 {
            f = image::imageops::blur(&f, self.defocus);
        }
        if self.motion.length_px > 0.0 {
            f = smear(&f, self.motion);
        }
        let mut rng = (self.noise > 0.0).then(|| ChaCha8Rng::seed_from_u64(self.seed ^ frame.wrapping_mul(0x9E37_79B9_7F4A_7C15)));
        let tone = |v: f32| if self.gamma == 1.0 { v } else { 255.0 * (v / 255.0).powf(self.gamma) };
        let mut out = RgbImage::new(w, h);
        for (o, p) in out.pixels_mut().zip(f.pixels()) {
            let n = rng.as_mut().map_or(0.0, |r| (crate::standard_normal(r) * self.noise as f64) as f32);
            for c in 0..3 {
                let v = ((p.0[c] * self.exposure + n) * self.white_balance[c]).clamp(0.0, 255.0);
                o.0[c] = tone(v).round().clamp(0.0, 255.0) as u8;
            }
        }
        match self.jpeg {
            Some(q) => jpeg_round_trip(&out, q),
            None => out,
        }
    }
}

/// The conditions in words, in the order they are applied (`as recorded` for none).
impl std::fmt::Display for Imperfections {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.is_none() {
            return f.write_str("as recorded");
        }
        let c = self;
        let mut parts = Vec::new();
        if c.defocus > 0.0 {
            parts.push(format!("defocus sigma {} px", c.defocus));
        }
        if c.motion.length_px > 0.0 {
            parts.push(format!("motion blur {} px at {} deg", c.motion.length_px, c.motion.angle_deg));
        }
        if c.exposure != 1.0 {
            parts.push(format!("exposure x{}", c.exposure));
        }
        if c.noise > 0.0 {
            parts.push(format!("noise sd {} grey levels", c.noise));
        }
        if c.white_balance != [1.0; 3] {
            let [r, g, b] = c.white_balance;
            parts.push(format!("white balance R x{r:.3} G x{g:.3} B x{b:.3}"));
        }
        if c.gamma != 1.0 {
            parts.push(format!("tone curve gamma {}", c.gamma));
        }
        if let Some(q) = c.jpeg {
            parts.push(format!("JPEG quality {q}"));
        }
        f.write_str(&parts.join(", "))
    }
}

/// The mean of `f` along a segment of `m.length_px` centred on each pixel: a box of that width
/// along the motion, integrated by the midpoint rule at a sample a pixel or closer (bilinear,
/// edges extended; 5 px horizontal is the 5-tap box).
fn smear(f: &image::Rgb32FImage, m: MotionBlur) -> image::Rgb32FImage {
    let (w, h) = f.dimensions();
    let n = (m.length_px.ceil() as usize).max(2);
    let (sin, cos) = m.angle_deg.to_radians().sin_cos();
    let steps: Vec<(f32, f32)> = (0..n)
        .map(|i| {
            let t = m.length_px * ((i as f32 + 0.5) / n as f32 - 0.5);
            (t * cos, t * sin)
        })
        .collect();
    let at = |x: f32, y: f32| -> [f32; 3] {
        let x = x.clamp(0.0, (w - 1) as f32);
        let y = y.clamp(0.0, (h - 1) as f32);
        let (x0, y0) = (x.floor() as u32, y.floor() as u32);
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let p = |x, y| f.get_pixel(x, y).0;
        let (a, b, c, d) = (p(x0, y0), p(x1, y0), p(x0, y1), p(x1, y1));
        [0, 1, 2].map(|k| (a[k] * (1.0 - fx) + b[k] * fx) * (1.0 - fy) + (c[k] * (1.0 - fx) + d[k] * fx) * fy)
    };
    image::ImageBuffer::from_fn(w, h, |x, y| {
        let mut s = [0f32; 3];
        for &(dx, dy) in &steps {
            let v = at(x as f32 + dx, y as f32 + dy);
            for k in 0..3 {
                s[k] += v[k];
            }
        }
        image::Rgb(s.map(|v| v / n as f32))
    })
}

/// `rgb` through the `image` crate's JPEG encoder at `quality` and back.
pub fn jpeg_round_trip(rgb: &RgbImage, quality: u8) -> RgbImage {
    use image::ImageEncoder;
    let mut buf = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut buf, quality)
        .write_image(rgb.as_raw(), rgb.width(), rgb.height(), image::ExtendedColorType::Rgb8)
        .expect("an RGB frame encodes into memory");
    image::load_from_memory_with_format(&buf, image::ImageFormat::Jpeg)
        .expect("the encoder's own JPEG decodes")
        .to_rgb8()
}

#[cfg(test)]
mod tests;
