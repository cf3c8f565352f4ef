//! Detection in one camera frame with a model blob: template crop on the host, then the pipeline
//! on the crop (the firmware's fixed-point code by default).
//!
//! [`model`]: what the host takes from a blob (its template, crop, float engine and decoder);
//! [`colour`]: the colour stage's saliency per pixel;
//! [`pipeline`]: the float engine and the one definition of the error and the saliency;
//! [`fixed`]: the firmware's engine; [`blobs`]: the blob stage after the mask; [`report`]: a
//! detection as JSON and as a line; [`picture`](mod@picture): a detection drawn.
pub mod blobs;
pub mod colour;
pub mod fixed;
pub mod model;
pub mod picture;
pub mod pipeline;
pub mod report;
use crate::data::crop::Face;
use crate::detect::pipeline::Detection;
use crate::models::predictor::FacePredictor;
use anyhow::{ensure, Result};
use msr_shared::blob::Model;

pub use model::{crop_mode_of, cropper_of, dequantized_decoder, float_engine_of, parse_blob, template_of};
pub use picture::picture;
pub use report::{readable, reason, to_json};

/// Which engine runs the pipeline on a face crop.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum EngineArg {
    /// The firmware's fixed-point code, as on the board
    Fixed,
    /// Float reference (dense decoders only), from the blob's dequantized weights
    Float,
}

/// The pipeline on one face crop seen with the head at `head`, in `engine`.
pub fn detect_face(
    model: &Model,
    face: &Face,
    head: [f32; 2],
    engine: EngineArg,
) -> Result<Detection> {
    ensure!(
        head.iter().all(|a| a.is_finite()),
        "head angles must be finite"
    );
    ensure!(
        (face.crop.height, face.crop.width) == (model.face_h as u32, model.face_w as u32),
        "crop {}x{} does not match the model's face {}x{}",
        face.crop.width,
        face.crop.height,
        model.face_w,
        model.face_h
    );
    match engine {
        EngineArg::Fixed => crate::detect::fixed::detect(model, face, head),
        EngineArg::Float => {
            let dec = dequantized_decoder(model)?;
            let eng = float_engine_of(model);
            Ok(eng.detect(face.crop, &face.grey, dec.predict(head, &[]), head))
        }
    }
}
