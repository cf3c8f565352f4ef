//! Calibrating the board's self gate (`msr_firmware::self_gate`) from rendered frames: the
//! robot's own mirror image at rest and at the probe's two yaws, cropped as the PC crops them,
//! gives the crop-offset gain the board expects and the spread its tolerances must allow.
use crate::data::crop::{self, Cropper};
use anyhow::{ensure, Result};
use image::DynamicImage;
use msr_shared::blob::{set_self_gate, Model, SelfGate};
use msr_sim::body::BodyPose;
use msr_sim::render::{Renderer, Variation};
use msr_sim::Robot;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

/// How the gate is calibrated.
#[derive(Clone, Debug)]
pub struct GateCalibration {
    /// The probe's yaw offset each way, radians (4 degrees: inside the training poses, and a
    /// span wide enough that a pixel of rounding is a small part of it).
    pub amplitude: f32,
    /// Noise draws of each pose.
    pub draws: usize,
    pub seed: u64,
    /// From a head pose to a frame of it on the board: the frame's transfer (75 x 58 at
    /// 921600 baud: 47 ms), two servo periods and a margin.
    pub latency_ms: u16,
    pub timeout_ms: u16,
    pub min_frames: u8,
    /// Least rest tolerance, pixels: the header's whole-pixel offsets round by up to 0.5 at
    /// each pose.
    pub rest_floor_px: f32,
    /// Largest gain tolerance: another robot where the mirror image would be shifts its face
    /// crop by 3-6 % more than the own image in the sim (measured; the camera's own sideways
    /// travel is not matched by a face that turns with it).
    pub gain_tol_max: f32,
}

impl Default for GateCalibration {
    fn default() -> Self {
        GateCalibration {
            amplitude: 0.07,
            draws: 6,
            seed: 0,
            latency_ms: 100,
            timeout_ms: 2000,
            min_frames: 2,
            rest_floor_px: 1.5,
            gain_tol_max: 0.03,
        }
    }
}

/// What calibration measured.
#[derive(Clone, Debug, Serialize)]
pub struct GateCalibReport {
    pub gate: SelfGateJson,
    /// Per draw: measured gain (px/rad) and rest distance (px).
    pub gains: Vec<f64>,
    pub rest_px: Vec<f64>,
}

/// [`SelfGate`] for reports.
#[derive(Clone, Debug, Serialize)]
pub struct SelfGateJson {
    pub amplitude_rad: f32,
    pub gain_px_per_rad: f32,
    pub gain_tol: f32,
    pub rest_tol_px: f32,
    pub latency_ms: u16,
    pub timeout_ms: u16,
    pub min_frames: u8,
}

impl From<&SelfGate> for SelfGateJson {
    fn from(g: &SelfGate) -> Self {
        SelfGateJson {
            amplitude_rad: g.amplitude,
            gain_px_per_rad: g.gain,
            gain_tol: g.gain_tol,
            rest_tol_px: g.rest_tol,
            latency_ms: g.latency_ms,
            timeout_ms: g.timeout_ms,
            min_frames: g.min_frames,
        }
    }
}

/// Measures the gate's gain and tolerances for `robot`'s mirror image cropped by `cropper`.
pub fn calibrate(robot: Robot, cropper: &Cropper, c: &GateCalibration) -> Result<(SelfGate, GateCalibReport)> {
    ensure!(c.draws >= 2, "self-gate calibration needs at least 2 draws");
    let renderer = Renderer::new(robot);
    let mut rng = ChaCha8Rng::seed_from_u64(c.seed);
    let a = c.amplitude as f64;
    let mut x_at = |yaw: f64| -> Result<f64> {
        let r = renderer.render(&BodyPose::head(yaw, 0.0), None, &Variation::random(&mut rng));
        let grey = crop::to_grey(&DynamicImage::ImageRgb8(r.rgb));
        Ok(cropper.crop(&grey)?.crop.x as f64)
    };
    let (mut gains, mut rests) = (Vec::new(), Vec::new());
    for _ in 0..c.draws {
        let (x0, xp, xm) = (x_at(0.0)?, x_at(a)?, x_at(-a)?);
        gains.push((xp - xm) / (2.0 * a));
        rests.push((x0 - (xp + xm) / 2.0).abs());
    }
    let gain = gains.iter().sum::<f64>() / gains.len() as f64;
    ensure!(gain.abs() >= 10.0, "the face crop does not follow the head (gain {gain:.1} px/rad)");
    // Spread of the draws, and at least one whole pixel of rounding over the probe's span
    // (the probe's poses are the same every time, so the whole-pixel offsets round alike; a
    // wider floor would let another robot through, see `gain_tol_max`).
    let dev = gains.iter().map(|g| (g / gain - 1.0).abs()).fold(0.0, f64::max);
    let floor = 1.0 / (2.0 * a * gain.abs());
    let gain_tol = (3.0 * dev).max(floor).min(c.gain_tol_max as f64) as f32;
    let rest_tol = (3.0 * rests.iter().copied().fold(0.0, f64::max)).max(c.rest_floor_px as f64) as f32;
    let gate = SelfGate {
        amplitude: c.amplitude,
        gain: gain as f32,
        gain_tol,
        rest_tol,
        latency_ms: c.latency_ms,
        timeout_ms: c.timeout_ms,
        min_frames: c.min_frames,
    };
    ensure!(gate.is_valid(), "self-gate calibration gave values out of range: {gate:?}");
    Ok((gate, GateCalibReport { gate: (&gate).into(), gains, rest_px: rests }))
}

/// `blob` with a self gate calibrated for `robot` (replacing any it had).
pub fn attach(blob: &[u8], robot: Robot, c: &GateCalibration) -> Result<(Vec<u8>, GateCalibReport)> {
    let model = Model::parse(blob).map_err(|e| anyhow::anyhow!("model blob: {e}"))?;
    let cropper = crate::detect::cropper_of(&model)?;
    let (gate, report) = calibrate(robot, &cropper, c)?;
    let out = set_self_gate(blob, Some(gate)).map_err(|e| anyhow::anyhow!("self gate: {e}"))?;
    Ok((out, report))
}

/// `blob` without a self gate: the paper's behaviour, a confirmed mark reached at once.
pub fn detach(blob: &[u8]) -> Result<Vec<u8>> {
    set_self_gate(blob, None).map_err(|e| anyhow::anyhow!("model blob: {e}"))
}
