//! `msr detect`: one camera frame through a model blob's pipeline, printed (and drawn).
use crate::data::crop::load_grey;
use crate::detect::{cropper_of, detect_face, parse_blob, picture, read_blob, readable, to_json, EngineArg};
use anyhow::Result;
use msr_shared::joints::Joint;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The model blob (.msrm)
    #[arg(long)]
    pub model: PathBuf,
    /// The camera frame (PNG, any size at least the template's)
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
}

pub fn run(args: Args) -> Result<()> {
    let head = [args.head_yaw, args.head_pitch];
    // The angles the servos can report: finite and inside Nao's head limits.
    for (joint, a) in [(Joint::HeadYaw, head[0]), (Joint::HeadPitch, head[1])] {
        joint.validate(a).map_err(|e| anyhow::anyhow!("head angle: {e}"))?;
    }
    let bytes = read_blob(&args.model)?;
    let model = parse_blob(&bytes, &args.model)?;
    let frame = load_grey(&args.image)?;
    let face = cropper_of(&model)?.crop(&frame)?;
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

