//! What the host takes from a model blob: its face template and crop, and its statistics and decoder in float.
use crate::data::crop::{CropMode, Cropper};
use crate::detect::pipeline::{FloatEngine, Settings};
use crate::models::dense::{Dense, DenseDecoder};
use anyhow::{bail, Context, Result};
use image::GrayImage;
use msr_shared::blob::{LayerKind, Model};
use std::path::Path;

/// A blob's bytes parsed, the file's path in the error.
pub fn parse_blob<'a>(bytes: &'a [u8], path: &Path) -> Result<Model<'a>> {
    Model::parse(bytes).map_err(|e| anyhow::anyhow!("model {}: {e}", path.display()))
}

/// The blob's face template as a grey image.
pub fn template_of(model: &Model) -> Result<GrayImage> {
    let t = model
        .template
        .context("the model blob holds no face template")?;
    GrayImage::from_raw(t.w as u32, t.h as u32, t.pixels.to_vec())
        .context("face template is malformed")
}

/// How the host crops faces for this model (whole pixels for a blob without a template).
pub fn crop_mode_of(model: &Model) -> CropMode {
    model.template.map_or(CropMode::Pixel, |t| t.crop)
}

/// The blob's template and crop mode: how to cut this model's faces from camera frames.
pub fn cropper_of(model: &Model) -> Result<Cropper> {
    Ok(Cropper::new(template_of(model)?, crop_mode_of(model)).with_colour(model.chroma.is_some()))
}

/// The float engine with the blob's statistics and settings.
pub fn float_engine_of(model: &Model) -> FloatEngine {
    let q = |v: u16| v as f32 / 256.0;
    FloatEngine {
        mu: model.mu.iter().map(q).collect(),
        sigma: model.sigma.iter().map(q).collect(),
        settings: Settings::of(model),
        region: model.region,
        reach: Some(model.reach),
        face_w: model.face_w as usize,
        pool: model.novelty.pool,
        spread_ref: model.novelty.spread_ref,
        pose: model.pose.map(|p| {
            let cells: Vec<_> = (0..p.grid.len()).filter_map(|k| p.tables(k)).collect();
            crate::detect::pipeline::PoseTables {
                grid: p.grid,
                mu: cells.iter().map(|(m, _)| m.iter().map(q).collect()).collect(),
                sigma: cells.iter().map(|(_, s)| s.iter().map(q).collect()).collect(),
            }
        }),
    }
}

/// The blob's decoder in float (weights and biases divided by their scales).
pub fn dequantized_decoder(model: &Model) -> Result<DenseDecoder> {
    let mut layers = Vec::new();
    for (i, l) in model.layers.iter().enumerate() {
        if l.kind != LayerKind::Dense {
            bail!(
                "layer {i} is {:?}: the float engine runs dense decoders only (the fixed engine runs every decoder)",
                l.kind
            );
        }
        let ws = 2f32.powi(-(l.w_shift as i32));
        let bs = 2f32.powi(-(l.w_shift as i32 + l.in_shift as i32));
        layers.push(Dense {
            n_in: l.input.len(),
            n_out: l.output.len(),
            w: (0..l.weight_count())
                .map(|k| l.weight(k) as f32 * ws)
                .collect(),
            b: (0..l.bias_count()).map(|k| l.bias(k) as f32 * bs).collect(),
            act: l.activation,
        });
    }
    Ok(DenseDecoder {
        layers,
        face_h: model.face_h as usize,
        face_w: model.face_w as usize,
    })
}
