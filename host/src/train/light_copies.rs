//! Light copies: the error statistics of a recording made under one light, widened to the
//! lights the robot will meet.
//!
//! The photometric fit takes a gain and an offset back from every frame
//! ([`crate::detect::pipeline::light_fit`]); what it leaves (a lamp lights the face's lit side
//! more than its shadows) is what the statistics must cover. `msr demo` renders half its
//! training frames under varied light for that. A recording has one light: its statistics
//! know nothing else, and a lamp switched on afterwards fires on every unmarked frame (red,
//! `msr dataset --light fixed` as the training set: 1.000 false alarms under `--light lamp`;
//! docs/light.md, "A recording under one light").
//!
//! So each training face adds [`LightCopies::copies`] faces to the statistics (never to the
//! decoder's training), each under a light of its own, drawn per copy:
//! 1. a tone curve `I^g`, `g` within `1 +- gamma` (`I` in 0..1): a stronger or weaker lamp
//!    changes the lit parts of the face more than the shadows, which no line through the
//!    grey levels takes back;
//! 2. a shading gradient `1 + a x + b y`, `a` and `b` within `+- gradient` (`x`, `y` from -1
//!    to 1 across the face): a lamp that moved or a window's light from one side;
//! 3. a gain within 0.8..1.2 and an offset within +-8 grey levels, which the fit takes back:
//!    they make each copy's fit do what it does on a real frame;
//! 4. rounded to whole grey levels and clipped at 0 and 255, as a camera codes them.
//!
//! The prediction a copy is compared with is the face's own (a decoder's prediction depends on
//! the head pose only), so copies are made for decoders; an autoencoder takes none. Seeded:
//! the same recording and seed give the same statistics.

use super::error::ConfigError;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// How many copies of each training face, under which lights ([the module doc](self)).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LightCopies {
    /// Copies per training face; 0: the statistics of the faces alone.
    pub copies: u8,
    /// Largest shading gradient, a share of the grey level from the face's centre to its edge.
    pub gradient: f32,
    /// Largest change of the tone curve's exponent.
    pub gamma: f32,
    /// Seed of the lights drawn.
    pub seed: u64,
}

impl LightCopies {
    /// No copies (the paper's statistics; what `msr demo` uses, whose training frames are
    /// rendered under varied light).
    pub const NONE: LightCopies = LightCopies { copies: 0, gradient: 0.0, gamma: 0.0, seed: 0 };

    /// [`LightCopies::NONE`], for serde's default.
    pub fn none() -> LightCopies {
        LightCopies::NONE
    }

    /// `msr train`'s default, measured on the red and skin robots (docs/light.md).
    pub const DEFAULT: LightCopies = LightCopies { copies: 4, gradient: 0.07, gamma: 0.2, seed: 0 };

    /// Amplitudes that keep a copy a face: finite, a gradient under 0.5, a gamma under 0.5.
    pub fn check(&self) -> Result<(), ConfigError> {
        if !(self.gradient.is_finite() && (0.0..0.5).contains(&self.gradient)) {
            return Err(ConfigError::LightGradient(self.gradient));
        }
        if !(self.gamma.is_finite() && (0.0..0.5).contains(&self.gamma)) {
            return Err(ConfigError::LightGamma(self.gamma));
        }
        Ok(())
    }

    /// The lights' generator: one per statistics run, so that every face's copies differ.
    pub fn rng(&self) -> ChaCha8Rng {
        ChaCha8Rng::seed_from_u64(self.seed ^ 0x6c69_6768_74)
    }

    /// The copies of one face (`w` wide, grey/255 in 0..1), drawing their lights from `rng`.
    pub fn of(&self, face: &[f32], w: usize, rng: &mut ChaCha8Rng) -> Vec<Vec<f32>> {
        if w == 0 {
            return Vec::new();
        }
        let h = face.len() / w;
        let unit = |i: usize, n: usize| if n > 1 { 2.0 * i as f32 / (n - 1) as f32 - 1.0 } else { 0.0 };
        (0..self.copies)
            .map(|_| {
                let g = 1.0 + self.draw(rng, self.gamma);
                let (a, b) = (self.draw(rng, self.gradient), self.draw(rng, self.gradient));
                let gain = rng.gen_range(0.8..=1.2f32);
                let offset = rng.gen_range(-8.0..=8.0f32);
                face.iter()
                    .enumerate()
                    .map(|(i, &v)| {
                        let shade = 1.0 + a * unit(i % w, w) + b * unit(i / w, h);
                        let grey = v.clamp(0.0, 1.0).powf(g) * shade * gain * 255.0 + offset;
                        grey.round().clamp(0.0, 255.0) / 255.0
                    })
                    .collect()
            })
            .collect()
    }

    fn draw(&self, rng: &mut ChaCha8Rng, amplitude: f32) -> f32 {
        if amplitude > 0.0 {
            rng.gen_range(-amplitude..=amplitude)
        } else {
            0.0
        }
    }
}

impl Default for LightCopies {
    fn default() -> Self {
        LightCopies::DEFAULT
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn face(w: usize, h: usize) -> Vec<f32> {
        (0..w * h).map(|i| 0.2 + 0.6 * ((i % w) as f32 / w as f32)).collect()
    }

    #[test]
    fn copies_are_seeded_faces_of_whole_grey_levels() {
        let (w, h) = (12, 9);
        let f = face(w, h);
        let c = LightCopies::DEFAULT;
        let a = c.of(&f, w, &mut c.rng());
        assert_eq!(a, c.of(&f, w, &mut c.rng()), "the same seed, the same copies");
        assert_eq!(a.len(), 4);
        assert_ne!(a[0], a[1], "each copy under a light of its own");
        for copy in &a {
            assert_eq!(copy.len(), f.len());
            assert!(copy.iter().all(|v| (0.0..=1.0).contains(v) && (v * 255.0 - (v * 255.0).round()).abs() < 1e-3));
        }
        let other = LightCopies { seed: 1, ..c };
        assert_ne!(a, other.of(&f, w, &mut other.rng()));
        assert!(LightCopies::NONE.of(&f, w, &mut c.rng()).is_empty());
        assert!(c.of(&f, 0, &mut c.rng()).is_empty(), "a face of no width has no copies");
    }

    #[test]
    fn without_gradient_and_gamma_a_copy_is_the_face_under_a_gain_and_an_offset() {
        let (w, h) = (10, 6);
        let f = face(w, h);
        let c = LightCopies { gradient: 0.0, gamma: 0.0, ..LightCopies::DEFAULT };
        for copy in c.of(&f, w, &mut c.rng()) {
            // Two pixels fix the line; every other lies on it to the rounding.
            let (x0, x1) = (f[0] * 255.0, f[w - 1] * 255.0);
            let (y0, y1) = (copy[0] * 255.0, copy[w - 1] * 255.0);
            let gain = (y1 - y0) / (x1 - x0);
            for (&x, &y) in f.iter().zip(&copy) {
                assert!((y0 + gain * (x * 255.0 - x0) - y * 255.0).abs() <= 1.5, "{x} -> {y}");
            }
        }
    }

    #[test]
    fn out_of_range_amplitudes_are_refused() {
        assert!(LightCopies::DEFAULT.check().is_ok());
        assert!(LightCopies::NONE.check().is_ok());
        for bad in [LightCopies { gradient: 0.5, ..LightCopies::DEFAULT }, LightCopies { gamma: f32::NAN, ..LightCopies::DEFAULT }, LightCopies { gamma: -0.1, ..LightCopies::DEFAULT }] {
            assert!(bad.check().is_err(), "{bad:?}");
        }
    }
}
