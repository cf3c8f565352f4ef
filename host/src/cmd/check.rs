//! What every command checks before it does any work: each argument's range, in the unit its flag
//! names, and that no output path names an input or another output (and that each output's
//! folder can be written). One place, so that every command is held to the same rules.
use super::Command;
use crate::fsio;
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};

/// Most mirror-test trials one run takes (each takes seconds; the results are kept in memory).
pub const MAX_TRIALS: usize = 100_000;
/// Most frames `msr dataset` and `msr demo` render (file names have six digits).
pub const MAX_FRAMES: usize = 1_000_000;
/// Slowest and fastest frame rate `msr run` streams at, frames per second.
pub const FPS_RANGE: (f64, f64) = (0.1, 1000.0);
/// Serial line rates `msr run` accepts, baud.
pub const BAUD_RANGE: (u32, u32) = (1200, 20_000_000);
/// Longest wait for a board's answer, milliseconds.
pub const MAX_TIMEOUT_MS: u64 = 600_000;

fn int<T: PartialOrd + std::fmt::Display + Copy>(flag: &str, v: T, lo: T, hi: T, unit: &str) -> Result<()> {
    if v < lo || v > hi {
        return Err(super::usage(format!("{flag} must be in {lo}..={hi}{unit}, got {v}")));
    }
    Ok(())
}

/// A number as a person writes it: plain in the usual range, else with an exponent.
fn num(v: f64) -> String {
    if v == 0.0 || (1e-3..1e7).contains(&v.abs()) {
        let s = format!("{v:.4}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        format!("{v:e}")
    }
}

fn line_noise(n: &super::line_noise::LineNoise) -> Result<()> {
    real("--ber", n.ber, 0.0, 1.0, " (errors per bit)")?;
    real("--burst-rate", n.burst_rate, 0.0, 1.0, " (bursts per byte)")?;
    int("--burst-len", n.burst_len, 1, 65_536, " bytes")
}

/// The camera's imperfections, each in its flag's unit.
fn camera(c: &super::imperfect::CameraFlags) -> Result<()> {
    let (lo, hi) = msr_sim::imperfect::Imperfections::EXPOSURE;
    real("--exposure", c.exposure, lo as f64, hi as f64, "")?;
    let (lo, hi) = msr_sim::imperfect::Imperfections::GAMMA;
    real("--gamma", c.gamma, lo as f64, hi as f64, "")?;
    let (lo, hi) = msr_sim::imperfect::Imperfections::KELVIN;
    real("--colour-temperature", c.colour_temperature, lo as f64, hi as f64, " K")?;
    if !c.white_balance.is_empty() {
        if c.white_balance.len() != 3 {
            return Err(super::usage(format!(
                "--white-balance takes three gains R,G,B, got {}",
                c.white_balance.len()
            )));
        }
        let (lo, hi) = msr_sim::imperfect::Imperfections::GAIN;
        for g in &c.white_balance {
            real("--white-balance", *g, lo as f64, hi as f64, " (a gain)")?;
        }
    }
    let (lo, hi) = msr_sim::imperfect::Imperfections::NOISE;
    real("--noise", c.noise, lo as f64, hi as f64, " grey levels")?;
    let (lo, hi) = msr_sim::imperfect::Imperfections::DEFOCUS;
    real("--defocus", c.defocus, lo as f64, hi as f64, " px")?;
    let (lo, hi) = msr_sim::imperfect::Imperfections::MOTION;
    real("--motion-blur", c.motion_blur, lo as f64, hi as f64, " px")?;
    real("--motion-angle", c.motion_angle, -360.0, 360.0, " deg")?;
    if let Some(q) = c.jpeg {
        int("--jpeg", q, 1, 100, " (quality)")?;
    }
    Ok(())
}

/// Camera flags on a command whose frames may come from elsewhere than the sim: only with `--sim`.
fn camera_for_sim(c: &super::imperfect::CameraFlags, sim: bool) -> Result<()> {
    camera(c)?;
    if !sim && !c.imperfections(0).is_none() {
        return Err(super::usage(
            "the camera flags (--exposure, --gamma, --colour-temperature, --white-balance, --noise, --defocus, \
             --motion-blur, --jpeg) change the sim's camera: give --sim",
        ));
    }
    Ok(())
}

/// The error's pooling radius and the pose grid, as `msr train` and `msr demo` take them.
fn novelty_flags(pool: u8, pose_bins: u8) -> Result<()> {
    int("--pool", pool, 0, msr_shared::blob::MAX_POOL, " px (window radius; 0: per pixel)")?;
    let most = msr_shared::blob::MAX_POSE_BINS;
    if pose_bins == 1 || pose_bins > most {
        return Err(super::usage(format!("--pose-bins must be 0 (one set of statistics for all poses) or in 2..={most} cells per angle, got {pose_bins}")));
    }
    Ok(())
}

fn real(flag: &str, v: f64, lo: f64, hi: f64, unit: &str) -> Result<()> {
    if !(v.is_finite() && v >= lo && v <= hi) {
        return Err(super::usage(format!("{flag} must be a number in {}..={}{unit}, got {}", num(lo), num(hi), num(v))));
    }
    Ok(())
}

fn positive(flag: &str, v: f64, unit: &str) -> Result<()> {
    if !(v.is_finite() && v > 0.0) {
        return Err(super::usage(format!("{flag} must be a positive number{unit}, got {}", num(v))));
    }
    Ok(())
}

/// Every file a JSON file names (relative to its folder): the files of a published manifest, or
/// of `msr train`'s `decoder.json`.
fn named_files(json: &Path) -> Vec<PathBuf> {
    let dir = json.parent().unwrap_or(Path::new("."));
    let Ok(text) = std::fs::read_to_string(json) else { return Vec::new() };
    let Ok(v) = serde_json::from_str::<serde_json::Value>(&text) else { return Vec::new() };
    let mut out = Vec::new();
    let mut stack = vec![&v];
    while let Some(v) = stack.pop() {
        match v {
            serde_json::Value::String(s) if s.len() < 4096 => {
                let p = dir.join(s);
                if p.is_file() {
                    out.push(p);
                }
            }
            serde_json::Value::Array(a) => stack.extend(a),
            serde_json::Value::Object(o) => stack.extend(o.values()),
            _ => {}
        }
    }
    out
}

/// An output file's folder (or, when the folders are still to be made, the nearest one that
/// exists) must take a new file.
fn writable(flag: &str, p: &Path) -> Result<()> {
    if p.is_dir() {
        bail!("{flag} {} is a folder, not a file", p.display());
    }
    fsio::refuse_special(p).map_err(|e| anyhow::anyhow!("{flag} {e}"))?;
    let dir = nearest_existing(p.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new(".")));
    takes_new_files(flag, p, dir, fsio::temp_beside(p).file_name().unwrap_or_default())
}

/// Whether `dir`, the nearest existing folder of the output `p`, is a folder that takes a new
/// file (named `probe`, made and removed again).
fn takes_new_files(flag: &str, p: &Path, dir: &Path, probe: &std::ffi::OsStr) -> Result<()> {
    if !dir.is_dir() {
        bail!("{flag} {}: {} is not a folder", p.display(), dir.display());
    }
    let probe = dir.join(probe);
    std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
        .with_context(|| format!("{flag} {}: cannot write in {}", p.display(), dir.display()))?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

/// `dir` or the nearest of its parents that exists (`.` when none of a relative path does).
fn nearest_existing(dir: &Path) -> &Path {
    let mut dir = dir;
    while !dir.exists() {
        match dir.parent().filter(|d| !d.as_os_str().is_empty()) {
            Some(up) => dir = up,
            None => return Path::new("."),
        }
    }
    dir
}

/// An output folder: a folder (or none yet) whose nearest existing folder takes new files.
fn writable_dir(flag: &str, p: &Path) -> Result<()> {
    if p.exists() && !p.is_dir() {
        bail!("{flag} {} is a file, not a folder", p.display());
    }
    takes_new_files(flag, p, nearest_existing(p), format!(".msr-probe.tmp{}", std::process::id()).as_ref())
}

/// Output files: writable, not an input, not each other.
fn outputs(inputs: &[(&str, &Path)], outs: &[(&str, &Path)]) -> Result<()> {
    fsio::check_outputs(inputs, outs)?;
    for (f, p) in outs {
        writable(f, p)?;
    }
    Ok(())
}

/// Checks a parsed command line; `Ok` means the command may start.
pub fn check(c: &Command) -> Result<()> {
    match c {
        Command::Dataset(a) => {
            int("--count", a.count, 1, MAX_FRAMES, " frames")?;
            // The sim bounds the range in radians; the flag is in degrees, and so is its bound.
            let max_deg = (msr_sim::body::MAX_DATASET_HEAD_ANGLE.to_degrees() * 100.0).floor() / 100.0;
            real("--max-angle-deg", a.max_angle_deg, 0.0, max_deg, " deg")?;
            real("--test-fraction", a.test_fraction, 0.0, 1.0, "")?;
            real("--unmarked-test-fraction", a.unmarked_test_fraction, 0.0, 1.0, "")?;
            int("--reach-pairs", a.reach_pairs, 0, 100_000, " pairs")?;
            camera(&a.imperfect)?;
            writable_dir("--out", &a.out)?;
        }
        Command::Train(a) => {
            int("--epochs", a.epochs, 1, 100_000, "")?;
            int("--batch", a.batch, 1, 65_536, " frames")?;
            positive("--lr", a.lr, "")?;
            int("--lr-step", a.lr_step, 1, usize::MAX, " epochs")?;
            if !(a.lr_decay > 0.0 && a.lr_decay <= 1.0) {
                return Err(super::usage(format!("--lr-decay must be in (0, 1], got {}", num(a.lr_decay))));
            }
            real("--sigma-floor", a.sigma_floor, 0.0, 255.0, " grey levels")?;
            positive("--threshold", a.threshold, " (saliency units)")?;
            if let Some(p) = a.threshold_percentile {
                real("--threshold-percentile", p, 0.0, 100.0, " %")?;
            }
            int("--min-area", a.min_area, 1, u16::MAX, " px")?;
            novelty_flags(a.pool, a.pose_bins)?;
            fsio::check_out_dir(&[("--data", &a.data)], "--out", &a.out)?;
            writable_dir("--out", &a.out)?;
        }
        Command::TrainReach(a) => {
            int("--iterations", a.iterations, 1, 10_000_000, "")?;
            positive("--lr", a.lr, "")?;
            int("--restarts", a.restarts, 1, 1000, "")?;
            let side = crate::train::reach::sidecar_path(&a.out);
            outputs(
                &[("--inputs", &a.inputs), ("--targets", &a.targets)],
                &[("--out", &a.out), ("--out's .json", &side)],
            )?;
        }
        Command::LearnReach(a) => {
            int("--grid", a.grid, 2, 64, " postures")?;
            int("--refine", a.refine, 0, 6, " halvings")?;
            int("--max-pairs", a.max_pairs, 10, 100_000, " pairs")?;
            writable_dir("--out", &a.out)?;
            if let Some(m) = &a.model_out {
                outputs(&[("--model", &a.model)], &[("--model-out", m)])?;
            }
        }
        Command::Quantize(a) => {
            if let Some(t) = a.threshold {
                positive("--threshold", t, " (saliency units)")?;
            }
            let side = crate::train::reach::sidecar_path(&a.reach);
            let report = PathBuf::from(format!("{}.json", a.out.display()));
            let trained: Vec<PathBuf> = ["decoder.json", "autoencoder.json"]
                .iter()
                .map(|n| a.train.join(n))
                .filter(|p| p.is_file())
                .flat_map(|p| std::iter::once(p.clone()).chain(named_files(&p)))
                .collect();
            let mut ins: Vec<(&str, &Path)> = vec![("--reach", &a.reach), ("--reach's .json", &side)];
            ins.extend(trained.iter().map(|p| ("a file of --train", p.as_path())));
            if let Some(d) = &a.data {
                ins.push(("--data", d));
            }
            outputs(&ins, &[("--out", &a.out), ("--out's report", &report)])?;
        }
        Command::Import(a) => {
            if let Some(t) = a.threshold {
                positive("--threshold", t as f64, " (sigma units)")?;
            }
            let files = named_files(&a.manifest);
            let mut ins: Vec<(&str, &Path)> = vec![("the manifest", &a.manifest)];
            ins.extend(files.iter().map(|p| ("a file of the manifest", p.as_path())));
            outputs(&ins, &[("--out", &a.out)])?;
        }
        Command::Detect(a) => {
            camera(&a.imperfect)?;
            if let Some(p) = &a.png {
                if !p.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")) {
                    return Err(super::usage(format!("--png {} must end in .png (the picture is a PNG)", p.display())));
                }
                outputs(&[("--model", &a.model), ("--image", &a.image)], &[("--png", p)])?;
            }
        }
        Command::Blobs(a) => {
            int("--min-area", a.min_area, 1, u32::MAX, " px")?;
        }
        Command::Eval(a) => camera(&a.imperfect)?,
        Command::Bench(a) => {
            int("--reps", a.reps, 1, 100_000, "")?;
            // --save-models names its files after the models: checked as they are written.
        }
        Command::MirrorTest(a) => {
            int("--trials", a.trials, 1, MAX_TRIALS, "")?;
            line_noise(&a.noise)?;
            camera(&a.imperfect)?;
            real("--no-mark-share", a.no_mark_share, 0.0, 1.0, "")?;
            if let Some(ms) = a.disconnect_ms {
                int("--disconnect-ms", ms, 0, 60_000, " ms")?;
            }
            int("--disconnect-at-ms", a.disconnect_at_ms, 0, 60_000, " ms")?;
            if let Some(p) = a.parallel {
                int("--parallel", p, 1, 256, " trials")?;
            }
            let outs: Vec<(&str, &Path)> = [("--trials-out", &a.trials_out), ("--bus-log", &a.bus_log), ("--mcap", &a.mcap)]
                .into_iter()
                .filter_map(|(f, p)| p.as_deref().map(|p| (f, p)))
                .collect();
            outputs(&[("--model", &a.model)], &outs)?;
        }
        Command::Run(a) => {
            int("--baud", a.line.baud, BAUD_RANGE.0, BAUD_RANGE.1, " baud")?;
            real("--fps", a.fps, FPS_RANGE.0, FPS_RANGE.1, " frames per second")?;
            int("--timeout-ms", a.timeout_ms, 1, MAX_TIMEOUT_MS, " ms")?;
            int("--count", a.count, 1, MAX_FRAMES, " frames")?;
            int("--frame-timeout-ms", a.frame_timeout_ms, 1, MAX_TIMEOUT_MS, " ms")?;
            camera_for_sim(&a.imperfect, a.sim.is_some())?;
            if let Some(p) = &a.mcap {
                let mut ins: Vec<(&str, &Path)> = vec![("--model", &a.model)];
                ins.extend(a.frames.as_deref().map(|f| ("--frames", f)));
                outputs(&ins, &[("--mcap", p)])?;
            }
        }
        Command::Servos(a) => {
            int("--baud", a.baud, BAUD_RANGE.0, BAUD_RANGE.1, " baud")?;
            if let Some(secs) = a.seconds {
                real("--seconds", secs, 0.0, 1e6, " s")?;
            }
            if let Some(p) = &a.bus_log {
                outputs(&[], &[("--bus-log", p)])?;
            }
        }
        Command::Serve(a) => {
            if let Some(secs) = a.seconds {
                real("--seconds", secs, 0.0, 1e6, " s")?;
            }
            line_noise(&a.noise)?;
        }
        Command::Record(a) => {
            int("--baud", a.line.baud, BAUD_RANGE.0, BAUD_RANGE.1, " baud")?;
            int("--count", a.count, 1, MAX_FRAMES, " frames")?;
            // The sim and the joint table bound the pose; the range is in degrees.
            let max_deg = (msr_sim::body::MAX_DATASET_HEAD_ANGLE.to_degrees() * 100.0).floor() / 100.0;
            real("--range-deg", a.range_deg, 0.0, max_deg, " deg")?;
            real("--test-fraction", a.test_fraction, 0.0, 1.0, "")?;
            int("--timeout-ms", a.timeout_ms, 1, MAX_TIMEOUT_MS, " ms")?;
            int("--frame-timeout-ms", a.frame_timeout_ms, 1, MAX_TIMEOUT_MS, " ms")?;
            camera_for_sim(&a.imperfect, a.sim.is_some())?;
            if a.resume && a.force {
                return Err(super::usage("--resume and --force contradict each other: give one"));
            }
            writable_dir("--out", &a.out)?;
            if let Some(p) = &a.mcap {
                outputs(&[("--out", &a.out)], &[("--mcap", p)])?;
            }
        }
        Command::Status(a) => {
            int("--baud", a.line.baud, BAUD_RANGE.0, BAUD_RANGE.1, " baud")?;
            int("--timeout-ms", a.timeout_ms, 1, MAX_TIMEOUT_MS, " ms")?;
        }
        Command::Template(a) => {
            outputs(&[("--frame", &a.frame)], &[("--out", &a.out)])?;
        }
        Command::Demo(a) => {
            int("--frames", a.frames, 10, MAX_FRAMES, " frames")?;
            int("--epochs", a.epochs, 1, 100_000, "")?;
            int("--trials", a.trials, 1, MAX_TRIALS, "")?;
            int("--qemu-trials", a.qemu_trials, 0, a.trials, " (at most --trials)")?;
            int("--gate-trials", a.gate_trials, 0, MAX_TRIALS, "")?;
            novelty_flags(a.pool, a.pose_bins)?;
            if let Some(r) = &a.real {
                fsio::check_out_dir(&[("--real", r)], "--out", &a.out)?;
            }
        }
        Command::ImportBag(a) => {
            real("--max-head-speed-deg-s", a.max_head_speed_deg_s, 0.0, 1e4, " deg/s")?;
            real("--max-joint-gap-ms", a.max_joint_gap_ms, 0.0, 1e7, " ms")?;
            real("--test-fraction", a.test_fraction, 0.0, 1.0, "")?;
            super::import_bag::joint_names(&a.joint_names).map_err(|e| super::usage(e.to_string()))?;
            fsio::check_out_dir(&[("the bag", &a.bag), ("--template", &a.template)], "--out", &a.out)?;
            writable_dir("--out", &a.out)?;
        }
    }
    Ok(())
}
