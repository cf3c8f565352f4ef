//! A tiny synthetic "face in a mirror" for tests: a bright ellipse with two dark eyes that moves
//! with the head angles, on a gradient, with a little noise. Deterministic per seed.
use super::fit::Samples;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

pub fn face(h: usize, w: usize, head: [f32; 2], noise: f32, rng: &mut ChaCha8Rng) -> Vec<f32> {
    // +-5 degrees moves the face by about +-w/12 and +-h/12 pixels.
    let cx = w as f32 / 2.0 + head[0] * w as f32;
    let cy = h as f32 / 2.0 - head[1] * h as f32;
    let (rx, ry) = (w as f32 * 0.3, h as f32 * 0.35);
    let mut out = Vec::with_capacity(h * w);
    for r in 0..h {
        for c in 0..w {
            let (x, y) = (c as f32 + 0.5, r as f32 + 0.5);
            let mut v = 0.2 + 0.2 * r as f32 / h as f32;
            let d = ((x - cx) / rx).powi(2) + ((y - cy) / ry).powi(2);
            v += 0.5 / (1.0 + (8.0 * (d - 1.0)).exp());
            for ex in [-0.4f32, 0.4] {
                let e = ((x - cx - ex * rx) / (0.15 * rx)).powi(2) + ((y - cy + 0.25 * ry) / (0.15 * ry)).powi(2);
                v -= 0.45 / (1.0 + (8.0 * (e - 1.0)).exp());
            }
            v += noise * (rng.gen::<f32>() - 0.5) * 2.0;
            out.push(v.clamp(0.0, 1.0));
        }
    }
    out
}

pub fn samples(n: usize, h: usize, w: usize, seed: u64) -> Samples {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let lim = 5f32.to_radians();
    let mut s = Samples::default();
    for _ in 0..n {
        let head = [rng.gen_range(-lim..lim), rng.gen_range(-lim..lim)];
        s.faces.push(face(h, w, head, 0.02, &mut rng));
        s.heads.push(head);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::super::fit::{fit, HyperParams};
    use super::*;
    use crate::models::{Decoder, DecoderSpec};
    use burn::prelude::*;

    /// CPU time of this process, all threads (what Python's `time.process_time` reads).
    #[cfg(all(target_os = "linux", target_env = "gnu"))] // libc is a dependency there only
    fn cpu_seconds() -> f64 {
        let mut t = libc::timespec { tv_sec: 0, tv_nsec: 0 };
        // SAFETY: clock_gettime writes one timespec through a valid pointer.
        unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut t) };
        t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    fn cpu_seconds() -> f64 {
        f64::NAN
    }

    /// Timing probe: `cargo test -p msr-host --lib timing_probe -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn timing_probe() {
        let arch = std::env::var("ARCH").unwrap_or("conv".into());
        let epochs: usize = std::env::var("EPOCHS").ok().and_then(|v| v.parse().ok()).unwrap_or(50);
        let train = samples(1040, 58, 75, 1);
        let test = samples(260, 58, 75, 2);
        let device = Device::flex().autodiff();
        let spec = if arch == "mlp" { DecoderSpec::mlp(58, 75) } else { DecoderSpec::conv(58, 75) };
        let model = Decoder::new(&spec, 0, &device).unwrap();
        let hp = HyperParams { epochs, ..Default::default() };
        let cpu0 = cpu_seconds();
        let (_, h) = fit(model, &train, &test, &hp, &device, "probe", false).unwrap();
        let cpu = cpu_seconds() - cpu0;
        // CPU seconds too: on a loaded machine the wall time says more about the other jobs.
        println!(
            "{arch}: {epochs} epochs in {:.1} s ({cpu:.1} s CPU), train {:?} test {:?}",
            h.seconds,
            h.train_loss.last(),
            h.test_loss.last()
        );
        for (i, (a, b)) in h.train_loss.iter().zip(&h.test_loss).enumerate() {
            println!("{i} {a:.5} {b:.5}");
        }
    }
}

