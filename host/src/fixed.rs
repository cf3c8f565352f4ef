//! The fixed-point engine: the firmware's own pipeline (decoder, saliency, blobs, winner, reach),
//! built for the host, on a face crop.
use crate::crop::Face;
use crate::pipeline::Detection;
use anyhow::{bail, Result};
use msr_shared::blob::Model;

/// Runs the firmware pipeline on one face.
pub fn detect(_model: &Model, _face: &Face, _head: [f32; 2]) -> Result<Detection> {
    bail!("the firmware pipeline is not in this build yet; use --engine float")
}

/// Every 8-connected blob of `mask` (row-major `w x h`) and whether the stage overflowed.
pub fn blobs(mask: &[bool], w: usize, h: usize) -> Result<(Vec<crate::pipeline::Blob>, bool)> {
    // Until the firmware's blob stage lands: imageproc's labelling.
    Ok((crate::pipeline::label_blobs(mask, w, h), false))
}
