//! The fixed-point engine: the firmware's own pipeline (decoder, saliency, blobs, winner, reach),
//! built for the host, on a face crop. Nothing here re-implements a stage; it only converts the
//! firmware's results to the host's [`Detection`]. A face with chroma planes and a model with
//! chroma run the colour stage too.
use crate::data::crop::Face;
use crate::detect::pipeline::{face_error, saliency, Blob, Detection};
use anyhow::{anyhow, ensure, Result};
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
    // The face's chroma planes when it has them; a grey model ignores them.
    let planes = (!face.chroma.is_empty() && model.chroma.is_some()).then_some(&face.chroma[..]);
    let det = msr_firmware::detect_colour(
        ws,
        model,
        &settings,
        &face.grey,
        planes,
        [c.x as u16, c.y as u16],
        head,
    )
    .map_err(|e| anyhow!("firmware pipeline: {e}"))?;
    let pixels = model.face_pixels();
    // The extent: salient pixels, not those salient through their pooling window only.
    let mask: Vec<bool> = ws.mask(pixels).iter().map(|&m| m == 1).collect();
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
    let (mu, sigma, _) = model.stats_at(head);
    let mu: Vec<f32> = mu.iter().map(q).collect();
    let sigma: Vec<f32> = sigma.iter().map(q).collect();
    let spread = ws.spread().map(|v| v as f32 / 256.0);
    let sal = saliency(face_error(&face.grey, &predicted, model.face_w as usize, model.novelty.pool), &mu, &sigma, 0.0, spread[1], settings.normalisation, settings.sided);
    Ok(Detection {
        crop: c,
        predicted,
        saliency: sal,
        mask,
        blob: det.blob.map(|b| Blob::from(&b).offset(c.x, c.y)),
        joints: det.reach,
        light: det.light,
        spread,
        colour: planes.and_then(|p| {
            let c = model.chroma_at(head)?;
            let (sal, _) = crate::detect::colour::saliency(&c, &face.grey, p, model.face_h as usize, model.face_w as usize)?;
            Some(sal.into_iter().map(|v| v / c.threshold).collect())
        }),
    })
}
