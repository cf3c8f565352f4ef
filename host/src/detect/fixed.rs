//! The fixed-point engine: the firmware's own pipeline (decoder, saliency, blobs, winner, reach),
//! built for the host, on a face crop. Nothing here re-implements a stage; it only converts the
//! firmware's results to the host's [`Detection`].
use crate::data::crop::Face;
use crate::detect::pipeline::{saliency, Blob, Detection};
use anyhow::{anyhow, ensure, Result};
use msr_firmware::blobs::{self as fw_blobs, Labeller};
use msr_firmware::{Settings, Workspace};
use msr_shared::blob::Model;

/// Runs the firmware pipeline on one face, with the blob's own novelty settings.
pub fn detect(model: &Model, face: &Face, head: [f32; 2]) -> Result<Detection> {
    detect_with(&mut Box::new(Workspace::new()), model, face, head)
}

/// Same, reusing a workspace (its caches notice a model change by the blob's CRC).
pub fn detect_with(
    ws: &mut Workspace,
    model: &Model,
    face: &Face,
    head: [f32; 2],
) -> Result<Detection> {
    let settings = Settings::of(model);
    let c = face.crop;
    ensure!(
        c.x <= u16::MAX as u32 && c.y <= u16::MAX as u32,
        "crop offset out of range"
    );
    let det = msr_firmware::detect(
        ws,
        model,
        &settings,
        &face.grey,
        [c.x as u16, c.y as u16],
        head,
    )
    .map_err(|e| anyhow!("firmware pipeline: {e}"))?;
    let pixels = model.face_pixels();
    let mask: Vec<bool> = ws.mask(pixels).iter().map(|&m| m != 0).collect();
    let face_q88 = ws
        .decoder
        .face()
        .ok_or_else(|| anyhow!("firmware decoder gave no face"))?;
    // The board's prediction, Q8.8 grey levels -> grey/255.
    let predicted: Vec<f32> = face_q88
        .iter()
        .map(|&v| v as f32 / (256.0 * 255.0))
        .collect();
    // Continuous saliency of the board's prediction against the blob's Q8.8 statistics, for
    // pictures and AUROC; the mask itself is the firmware's.
    let q = |v: u16| v as f32 / 256.0;
    let mu: Vec<f32> = model.mu.iter().map(q).collect();
    let sigma: Vec<f32> = model.sigma.iter().map(q).collect();
    let sal = saliency(
        &face.grey,
        &predicted,
        &mu,
        &sigma,
        settings.normalisation,
        settings.sided,
    );
    Ok(Detection {
        crop: c,
        predicted,
        saliency: sal,
        mask,
        blob: det.blob.map(|b| to_blob(&b).offset(c.x, c.y)),
        joints: det.reach,
    })
}

fn to_blob(b: &fw_blobs::Blob) -> Blob {
    let a = b.area.max(1) as f64;
    Blob {
        area: b.area,
        box_xyxy: [b.x0 as u32, b.y0 as u32, b.x1 as u32, b.y1 as u32],
        centroid: [b.sum_x as f64 / a, b.sum_y as f64 / a],
    }
}

/// Widest mask `msr blobs` takes (the board's own labeller takes faces up to `MAX_FACE_W`).
pub const HOST_MAX_WIDTH: usize = 2 * HOST_RUNS - 1;
const HOST_RUNS: usize = 2048;
/// Enough slots for two rows of runs: the labeller cannot overflow.
const HOST_LABELS: usize = 2 * HOST_RUNS;

/// Every 8-connected blob of `mask` (row-major `w x h`) by the firmware's labeller, in raster
/// order of each blob's first pixel (OpenCV 5 numbers them in its own block order: compare as
/// sets), and whether it overflowed.
pub fn blobs(mask: &[bool], w: usize, h: usize) -> Result<(Vec<Blob>, bool)> {
    ensure!(
        w >= 1 && h >= 1 && w <= HOST_MAX_WIDTH && h < u16::MAX as usize,
        "mask {w}x{h} is outside 1..={HOST_MAX_WIDTH} x 1..{}",
        u16::MAX
    );
    ensure!(
        mask.len() == w * h,
        "mask has {} pixels, not {w}x{h}",
        mask.len()
    );
    let bytes: Vec<u8> = mask.iter().map(|&m| m as u8).collect();
    let mut lab: Box<Labeller<HOST_LABELS, HOST_RUNS>> = Box::new(Labeller::new());
    let mut found: Vec<fw_blobs::Blob> = Vec::new();
    let summary = lab
        .label(&bytes, w, h, |b| found.push(*b))
        .map_err(|e| anyhow!("firmware blob stage refused the mask: {e:?}"))?;
    found.sort_by_key(|b| b.first);
    Ok((found.iter().map(to_blob).collect(), summary.overflow))
}
