//! Detection in one camera frame with a model blob: template crop on the host, then the pipeline
//! on the crop (the firmware's fixed-point code by default).
pub mod pipeline;
pub mod fixed;
pub mod blobs;
use crate::data::crop::{CropBox, CropMode, Cropper, Face};
use crate::models::dense::{Dense, DenseDecoder};
use crate::detect::pipeline::{Detection, FloatEngine, Settings, JOINTS};
use crate::models::predictor::FacePredictor;
use anyhow::{bail, ensure, Context, Result};
use image::GrayImage;
use msr_shared::blob::{LayerKind, Model};

use std::path::Path;

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum EngineArg {
    /// The firmware's fixed-point code, as on the board
    Fixed,
    /// Float reference (dense decoders only), from the blob's dequantized weights
    Float,
}

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
    Ok(Cropper::new(template_of(model)?, crop_mode_of(model)))
}

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
                "layer {i} is {:?}: the float engine runs dense decoders only (use --engine fixed)",
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

/// The JSON the issue specifies (full-frame pixels, inclusive boxes), keys in the documented order.
pub fn to_json(d: &Detection) -> String {
    #[derive(serde::Serialize)]
    struct Out {
        crop: CropBox,
        blob: Option<crate::detect::pipeline::Blob>,
        joints: Option<Joints>,
        /// Why nothing can be detected in this frame: "NoFace", "SceneChanged", or null.
        reason: Option<&'static str>,
        /// The photometric fit: the prediction's grey per observed grey, and the offset.
        light: Light,
    }
    #[derive(serde::Serialize)]
    struct Light {
        gain: f32,
        offset: f32,
        correlation: f32,
        samples: u16,
        inliers: u16,
        /// The grey levels where the camera clipped, darkest and brightest: 0 and 255, or a
        /// plateau's (`msr_firmware::light::PLATEAU_SHARE`).
        clip: [u8; 2],
    }
    #[derive(serde::Serialize)]
    #[allow(non_snake_case)]
    struct Joints {
        HeadYaw: f32,
        HeadPitch: f32,
        LShoulderPitch: f32,
        LShoulderRoll: f32,
        LElbowRoll: f32,
    }
    let out = Out {
        crop: d.crop,
        blob: d.blob,
        joints: d.joints.map(|j| Joints {
            HeadYaw: j[0],
            HeadPitch: j[1],
            LShoulderPitch: j[2],
            LShoulderRoll: j[3],
            LElbowRoll: j[4],
        }),
        reason: reason(d),
        light: Light {
            gain: d.light.gain_f32(),
            offset: d.light.offset_grey(),
            correlation: d.light.correlation_milli as f32 / 1000.0,
            samples: d.light.samples,
            inliers: d.light.inliers,
            clip: d.light.clip,
        },
    };
    // Plain structs and finite floats: serialising cannot fail.
    serde_json::to_string(&out).unwrap_or_default()
}

/// Why a frame yields no detection whatever it shows: `NoFace` (the crop does not follow the
/// predicted face: black, white, covered, someone else), `SceneChanged` (a light the fit cannot
/// explain, or one that changed while the frame was taken); `None` when the face was seen.
pub fn reason(d: &Detection) -> Option<&'static str> {
    use crate::detect::pipeline::Verdict;
    match d.light.verdict {
        Verdict::Face => None,
        Verdict::NoFace => Some("NoFace"),
        Verdict::SceneChanged => Some("SceneChanged"),
    }
}

pub fn readable(d: &Detection) -> String {
    let c = d.crop;
    if let Some(r) = reason(d) {
        return format!(
            "no detection: {r} (crop at ({}, {}); light fit gain {:.2}, offset {:.1}, correlation {:.2})",
            c.x,
            c.y,
            d.light.gain_f32(),
            d.light.offset_grey(),
            d.light.correlation_milli as f32 / 1000.0
        );
    }
    let mut s = format!("face at ({}, {}) {}x{}: ", c.x, c.y, c.width, c.height);
    match d.blob {
        None => s += "no mark",
        Some(b) => {
            s += &format!(
                "mark of {} px, box {:?}, centroid ({:.1}, {:.1})",
                b.area, b.box_xyxy, b.centroid[0], b.centroid[1]
            );
            if let Some(j) = d.joints {
                let parts: Vec<String> = JOINTS
                    .iter()
                    .zip(j)
                    .map(|(n, v)| format!("{n} {v:.3}"))
                    .collect();
                s += &format!("; reach: {}", parts.join(", "));
            }
        }
    }
    s
}

/// Frame with crop and detection | observed face over predicted face | saliency over mask.
pub fn picture(frame: &GrayImage, face: &[u8], d: &Detection, threshold: f32) -> image::RgbImage {
    use image::Rgb;
    use imageproc::drawing::{draw_cross_mut, draw_hollow_rect_mut};
    use imageproc::rect::Rect;
    let (fw, fh) = frame.dimensions();
    let (w, h) = (d.crop.width, d.crop.height);
    let k = 2u32;
    let mut img =
        image::RgbImage::from_pixel(fw + 2 * k * w + 8, fh.max(2 * k * h + 4), Rgb([32, 32, 32]));
    for (x, y, p) in frame.enumerate_pixels() {
        img.put_pixel(x, y, Rgb([p[0]; 3]));
    }
    let red = Rgb([255, 40, 40]);
    let green = Rgb([40, 220, 40]);
    draw_hollow_rect_mut(
        &mut img,
        Rect::at(d.crop.x as i32, d.crop.y as i32).of_size(w, h),
        green,
    );
    if let Some(b) = d.blob {
        let [x0, y0, x1, y1] = b.box_xyxy;
        draw_hollow_rect_mut(
            &mut img,
            Rect::at(x0 as i32, y0 as i32).of_size(x1 - x0 + 1, y1 - y0 + 1),
            red,
        );
        draw_cross_mut(
            &mut img,
            Rgb([255, 255, 0]),
            b.centroid[0].round() as i32,
            b.centroid[1].round() as i32,
        );
    }
    let mut panel = |ox: u32, oy: u32, f: &dyn Fn(usize) -> Rgb<u8>| {
        for y in 0..h * k {
            for x in 0..w * k {
                let i = ((y / k) * w + x / k) as usize;
                img.put_pixel(ox + x, oy + y, f(i));
            }
        }
    };
    let x1 = fw + 4;
    let x2 = x1 + k * w + 4;
    let y2 = k * h + 4;
    panel(x1, 0, &|i| Rgb([face[i]; 3]));
    panel(x1, y2, &|i| {
        let g = (d.predicted[i] * 255.0).round().clamp(0.0, 255.0) as u8;
        Rgb([g; 3])
    });
    // Saliency: black at 0, white at the threshold, red above it.
    panel(x2, 0, &|i| {
        let s = d.saliency[i].max(0.0) / threshold;
        if s > 1.0 {
            Rgb([255, 0, 0])
        } else {
            Rgb([(s * 255.0) as u8; 3])
        }
    });
    panel(x2, y2, &|i| {
        if d.mask[i] {
            Rgb([255, 255, 255])
        } else {
            Rgb([0, 0, 0])
        }
    });
    img
}
