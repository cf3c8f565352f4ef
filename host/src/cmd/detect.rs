//! `msr detect`: one camera frame through a model blob's pipeline, printed (and drawn).
use crate::data::crop::load_colour;
use crate::detect::{cropper_of, detect_face, parse_blob, picture, readable, to_json, EngineArg};
use crate::fsio::read_blob;
use anyhow::{Context, Result};
use msr_shared::joints::Joint;
use std::path::PathBuf;

/// `msr detect`'s flags: the model, the frame with its head angles, the engine and the outputs.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The model blob (.msrm)
    #[arg(long)]
    pub model: PathBuf,
    /// The camera frame (PNG, 320x240, or larger with that aspect ratio: scaled down)
    #[arg(long)]
    pub image: PathBuf,
    /// HeadYaw when the frame was taken, radians
    #[arg(long, allow_hyphen_values = true)]
    pub head_yaw: f32,
    /// HeadPitch when the frame was taken, radians
    #[arg(long, allow_hyphen_values = true)]
    pub head_pitch: f32,
    /// Print JSON instead of a readable line
    #[arg(long)]
    pub json: bool,
    /// Write a picture of the frame, the prediction, the saliency and the detection
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Which pipeline runs on the crop
    #[arg(long, value_enum, default_value_t = EngineArg::Fixed)]
    pub engine: EngineArg,
    /// The camera's imperfections, on the frame (its colour, before grey, the scaling and the
    /// crop; the noise the same draws on every run)
    #[command(flatten)]
    pub imperfect: super::imperfect::CameraFlags,
}

/// Checks the head angles, crops the frame's face, detects, and prints the result (a line or
/// JSON), with the picture when `--png` asks for it.
pub fn run(args: Args) -> Result<()> {
    let head = [args.head_yaw, args.head_pitch];
    // The angles the servos can report: finite and inside Nao's head limits.
    for (joint, a) in [(Joint::HeadYaw, head[0]), (Joint::HeadPitch, head[1])] {
        joint.validate(a).map_err(|e| super::usage(format!("head angle: {e}")))?;
    }
    let bytes = read_blob(&args.model)?;
    let model = parse_blob(&bytes, &args.model)?;
    check_trained_range(&model, head)?;
    // The same rule as `msr run`'s and `msr record`'s frames: the model's frame size, or larger
    // and scaled down; never scaled up.
    let size = crate::camera::SourceOptions::default().size;
    let camera = args.imperfect.imperfections(0);
    let (grey, rgb) = load_colour(&args.image, &camera, 0)?;
    let frame = crate::camera::fit(&grey, size)
        .with_context(|| format!("--image {}", args.image.display()))?;
    // A colour image at the model's frame size carries its chroma to a model with colour; a
    // scaled or grey one runs on grey.
    let face = match rgb.filter(|c| c.dimensions() == frame.dimensions()) {
        Some(c) => cropper_of(&model)?.crop_colour(&frame, &c)?,
        None => cropper_of(&model)?.crop(&frame)?,
    };
    let det = detect_face(&model, &face, head, args.engine)?;
    if args.json {
        println!("{}", to_json(&det));
    } else {
        println!("{}", readable(&det));
    }
    if let Some(p) = &args.png {
        let pic = picture(&frame, &face.grey, &det, model.novelty.threshold);
        crate::fsio::write_with(p, |tmp| Ok(pic.save(tmp)?))?;
    }
    Ok(())
}

/// How far past the edge of the head poses a model was trained on `msr detect` still answers,
/// as a share of the range's width: the decoder extrapolates there, and its "marks" are its own
/// errors.
pub const RANGE_MARGIN: f32 = 0.25;

/// Refuses a head pose far outside the range the blob was trained on. The blob knows the range
/// when it has pose cells (its grid spans the training poses, `msr train`'s default); a blob
/// without them (the paper's layout, an imported model) does not, and only the joint range holds.
pub fn check_trained_range(model: &msr_shared::blob::Model, head: [f32; 2]) -> Result<()> {
    let Some(pose) = &model.pose else { return Ok(()) };
    let g = pose.grid;
    for (a, name) in [(0, "yaw"), (1, "pitch")] {
        let m = RANGE_MARGIN * (g.hi[a] - g.lo[a]);
        if head[a] < g.lo[a] - m || head[a] > g.hi[a] + m {
            anyhow::bail!(
                "head {name} {:.2} deg is far outside the {:.2}..{:.2} deg the model was trained on \
                 (more than {:.0} % of that range past its edge): its prediction there is a guess, \
                 and so is any mark",
                head[a].to_degrees(),
                g.lo[a].to_degrees(),
                g.hi[a].to_degrees(),
                RANGE_MARGIN * 100.0
            );
        }
    }
    Ok(())
}