//! The paper's table: detection on a dataset's test split.
//!
//! Rows: model (decoder, autoencoder) x weighting (sigma: the blob's statistics; none: Sigma = I,
//! i.e. sigma = 1 grey level everywhere, the paper's ablation) x engine (float, fixed). The fixed
//! engine is the firmware's pipeline on the blob (for "none", the blob with its sigma table set to
//! 1.0). Float rows use the trained models next to the blob (`msr train` output: `{name}.json`,
//! `{name}.mpk`, statistics and novelty settings), or for the decoder, when there is none, the
//! blob's dense decoder dequantized (the row's `source` says which). Rows that cannot be
//! made are listed under `absent` with the reason, never invented.
//!
//! Columns, over the test frames (crops as the dataset loader makes them):
//! - `overlap_over_mark_area`: mean over marked frames of |detected box ∩ mark| / mark pixels (the
//!   published code's measure; no detection counts 0);
//! - `precision_ai_over_ai_ad`: mean over marked frames of a_i / (a_i + a_d), a_i = salient mark
//!   pixels, a_d = salient pixels off the mark (the paper's measure; nothing salient counts 0);
//! - `hit_rate`: marked frames whose winning blob's centroid lies on the mark (its mask; its box
//!   when only a box is known);
//! - `false_alarm_rate`: unmarked frames with a detection;
//! - `image_auroc`: marked vs unmarked frames scored by their detection score (the highest
//!   threshold that still leaves a blob of `min_area`);
//! - `pixel_auroc`: every face pixel of every test frame, mark vs not, scored by saliency.
//!
//! Engine `fixed+colour` (a model with chroma): the fixed-point pipeline with the faces' chroma
//! planes, as the board runs it on a colour camera's frames; `fixed` is the same on grey alone.
//!
//! `quantized_agreement`: the share of test frames where the float and fixed decoder rows (sigma
//! weighting) agree: both find nothing, or both find a blob with centroids at most 1 px apart.
pub mod hue;
pub mod metrics;
use crate::data::{Dataset, Sample};
use crate::detect::{dequantized_decoder, float_engine_of, parse_blob};
use crate::fsio::read_blob;
use crate::eval::metrics::{auroc, detection_score};
use crate::detect::pipeline::{Detection, Settings};
use crate::models::predictor::FacePredictor;
use anyhow::{ensure, Context, Result};
use msr_shared::blob::{Model, CRC32};
use msr_sim::imperfect::Imperfections;
use msr_sim::layout::Split;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// One row of the table: one model, weighting and engine scored over the test frames. A score
/// is `None` where its frames are missing (no marked or no unmarked frame).
#[derive(Serialize, Deserialize, Debug, Clone)]
pub struct Row {
    /// `"decoder"` or `"autoencoder"`.
    pub model: String,
    /// `"sigma"` (the statistics' sigma) or `"none"` (sigma = 1 grey level everywhere).
    pub weighting: String,
    /// `"float"` or `"fixed"` (the firmware's pipeline on the blob).
    pub engine: String,
    /// Mean over marked frames of the winning blob's box pixels on the mark over the mark's
    /// pixels; a frame without a detection counts 0.
    pub overlap_over_mark_area: Option<f64>,
    /// Mean over marked frames of a_i / (a_i + a_d): salient pixels on the mark over all salient
    /// pixels; a frame with nothing salient counts 0.
    pub precision_ai_over_ai_ad: Option<f64>,
    /// Share of marked frames whose winning blob's centroid lies on the mark.
    pub hit_rate: Option<f64>,
    /// Share of unmarked frames with a detection.
    pub false_alarm_rate: Option<f64>,
    /// AUROC of marked against unmarked frames, each scored by its detection score.
    pub image_auroc: Option<f64>,
    /// AUROC of every face pixel of every test frame, mark against not, scored by its saliency.
    pub pixel_auroc: Option<f64>,
    /// Where the model of this row came from.
    pub source: String,
    /// The test frames it got wrong: marks not found, unmarked frames that fired.
    #[serde(default)]
    pub wrong: Vec<Wrong>,
}

/// A test frame a row got wrong.
#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
pub struct Wrong {
    /// The frame's file.
    pub file: String,
    /// [HeadYaw, HeadPitch], radians.
    pub head: [f32; 2],
    /// `"no blob"` (a marked frame that found nothing), `"off the mark"` (the winning blob's
    /// centroid is not on it) or `"fired"` (an unmarked frame).
    pub what: String,
    /// The winning blob's area and centroid (full-frame pixels), if any.
    pub blob: Option<(u32, [f64; 2])>,
    /// The mark's pixels inside the face, on a marked frame.
    pub mark_pixels: Option<u32>,
    /// The frame's photometric fit's verdict, when it was not a face.
    pub verdict: Option<String>,
}

/// A row of the table that could not be made, and why.
#[derive(Serialize, Deserialize, Debug, Clone)]
pub struct Absent {
    /// `"decoder"` or `"autoencoder"`.
    pub model: String,
    /// `"sigma"` or `"none"`.
    pub weighting: String,
    /// `"float"` or `"fixed"`.
    pub engine: String,
    /// Why the row could not be made.
    pub reason: String,
}

/// The evaluation of one model blob on one dataset's test split: its rows, the rows it could
/// not make, and the conditions they were scored under.
#[derive(Serialize, Deserialize, Debug, Clone)]
pub struct Report {
    /// The dataset's folder.
    pub data: String,
    /// The model blob's path.
    pub blob: String,
    /// Frames in the test split.
    pub test_frames: usize,
    /// Test frames with a mark.
    pub marked: usize,
    /// Test frames without a mark.
    pub unmarked: usize,
    /// The blob's saliency threshold, in units of its normaliser.
    pub threshold: f32,
    /// The blob's own settings near one head pose, when it has them.
    pub region: Option<msr_shared::blob::PoseRegion>,
    /// The blob's smallest blob that counts as a detection, pixels.
    pub min_area: u16,
    /// The rows that could be made.
    pub rows: Vec<Row>,
    /// The rows that could not be made, with the reason.
    pub absent: Vec<Absent>,
    /// Share of test frames where the float and fixed decoder rows (sigma weighting) agree: both
    /// find nothing, or both a blob with centroids at most 1 px apart; `None` without both rows.
    pub quantized_agreement: Option<f64>,
    /// What the camera did to the test frames (`msr eval`'s camera flags and `--range`).
    #[serde(default)]
    pub camera: Camera,
}

const WEIGHTINGS: [&str; 2] = ["sigma", "none"];

/// The table for the model blob at `blob_path` on the test split of the dataset at `data`, the
/// frames as recorded.
pub fn evaluate(blob_path: &Path, data: &Path) -> Result<Report> {
    evaluate_with(blob_path, data, None)
}

/// [`evaluate`], with the float decoder taken from a published manifest when one is given.
pub fn evaluate_with(blob_path: &Path, data: &Path, manifest: Option<&Path>) -> Result<Report> {
    evaluate_lit(blob_path, data, manifest, &Camera::default())
}

/// The grey range a camera codes its frames in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Range {
    /// 0..=255, as the frames were recorded
    #[default]
    Full,
    /// 16..=235, as video luma (YUYV, most webcams) codes it: black lifted to 16, white at 235
    Limited,
}

/// Codes full-range grey levels in `range` (limited: `16 + round(219 v / 255)`).
pub fn code_range(grey: &mut [u8], range: Range) {
    if range == Range::Limited {
        for g in grey {
            *g = (16 + (*g as u32 * 219 + 127) / 255) as u8;
        }
    }
}

/// What a camera does to each test frame before detection: its imperfections on the colour
/// frame before grey and the crop ([`Imperfections`], in a camera's own order), then its video
/// coding of the grey ([`code_range`]). The default leaves the frames as recorded.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    /// The imperfections on each colour frame, before grey and the crop.
    pub imperfect: Imperfections,
    /// Grey range the faces are coded in.
    pub range: Range,
}

impl std::fmt::Display for Camera {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match (self.imperfect.is_none(), self.range) {
            (_, Range::Full) => write!(f, "{}", self.imperfect),
            (true, Range::Limited) => f.write_str("limited range (16..=235)"),
            (false, Range::Limited) => write!(f, "{}, limited range (16..=235)", self.imperfect),
        }
    }
}

/// [`evaluate_with`], every test face through `camera` first.
pub fn evaluate_lit(blob_path: &Path, data: &Path, manifest: Option<&Path>, camera: &Camera) -> Result<Report> {
    camera.imperfect.check()?;
    let bytes = read_blob(blob_path)?;
    let model = parse_blob(&bytes, blob_path)?;
    let published = match manifest {
        Some(m) => {
            imported_from(&model, blob_path, m)?;
            Some(published_float_decoder(m)?)
        }
        None => None,
    };
    let mut published = published;
    // Crop as the host would for this model.
    let crop = crate::detect::crop_mode_of(&model);
    let mut ds = Dataset::load_through(data, Some(Split::Test), crop, &camera.imperfect)
        .with_context(|| format!("cannot load dataset {}", data.display()))?;
    for s in ds.samples.iter_mut() {
        code_range(&mut s.face.grey, camera.range);
    }
    let test: Vec<&Sample> = ds.split(Split::Test).collect();
    ensure!(
        !test.is_empty(),
        "dataset {} has no test frames",
        data.display()
    );
    ensure!(
        ds.face_size() == (model.face_h as usize, model.face_w as usize),
        "dataset faces are {}x{}, the model's are {}x{}",
        ds.face_size().1,
        ds.face_size().0,
        model.face_w,
        model.face_h
    );
    let unit_sigma = with_unit_sigma(&bytes, &model)?;
    let none_model = parse_blob(&unit_sigma, blob_path)?;

    let mut rows = Vec::new();
    let mut absent = Vec::new();
    let mut dets: Vec<((&str, &str, &str), Vec<Detection>)> = Vec::new();
    let heads: Vec<[f32; 2]> = test.iter().map(|s| s.head).collect();
    let faces: Vec<Vec<f32>> = test.iter().map(|s| s.face_unit()).collect();

    // Float models: trained ones next to the blob; for the decoder, else the blob's own decoder.
    let dir = blob_path.parent().unwrap_or(Path::new("."));
    for name in ["decoder", "autoencoder"] {
        let from_manifest = if name == "decoder" {
            published.take()
        } else {
            None
        };
        let found = match from_manifest {
            Some(f) => Ok(Some(f)),
            None => trained_model(dir, name, ds.face_size(), crop),
        };
        let float = match found {
            Ok(Some(f)) => Ok(f),
            Ok(None) if name == "decoder" => blob_float_decoder(&model),
            Ok(None) => Err(format!(
                "no trained {name} next to {} (the training output folder holds {name}.json and \
                 {name}.mpk)",
                blob_path.display()
            )),
            Err(e) => Err(e),
        };
        let float = match float {
            Ok(f) => f,
            Err(reason) => {
                for weighting in WEIGHTINGS {
                    absent.push(Absent {
                        model: name.into(),
                        weighting: weighting.into(),
                        engine: "float".into(),
                        reason: reason.clone(),
                    });
                }
                continue;
            }
        };
        let predicted = float.predictor.predict_batch(&heads, &faces);
        for weighting in WEIGHTINGS {
            let mut eng = float_engine_of(&model);
            eng.mu = float.mu.clone();
            eng.sigma = if weighting == "sigma" {
                float.sigma.clone()
            } else {
                vec![1.0; float.sigma.len()]
            };
            eng.settings = float.settings;
            eng.region = float.region;
            eng.pose = float.pose.clone();
            if let (Some(p), false) = (&mut eng.pose, weighting == "sigma") {
                p.sigma.iter_mut().for_each(|s| s.iter_mut().for_each(|v| *v = 1.0));
            }
            let d: Vec<Detection> = test
                .iter()
                .zip(&predicted)
                .map(|(s, p)| eng.detect(s.face.crop, &s.face.grey, p.clone(), s.head))
                .collect();
            rows.push(row(
                name,
                weighting,
                "float",
                float.source.clone(),
                &test,
                &d,
                float.settings.min_area,
            ));
            dets.push(((name, "float", weighting), d));
        }
    }
    // Fixed point: the firmware's pipeline on the blob (a decoder: the board runs nothing else),
    // on grey as the paper; for a model with chroma, again with the faces' colour.
    let engines: &[&str] = if model.chroma.is_some() { &["fixed", "fixed+colour"] } else { &["fixed"] };
    for &engine in engines {
        for (weighting, m) in WEIGHTINGS.iter().zip([&model, &none_model]) {
            let mut d = Vec::with_capacity(test.len());
            let mut ws = Box::new(msr_firmware::Workspace::new());
            for s in &test {
                let grey;
                let face = if engine == "fixed" {
                    grey = crate::data::crop::Face { chroma: Vec::new(), ..s.face.clone() };
                    &grey
                } else {
                    &s.face
                };
                d.push(
                    crate::detect::fixed::detect_with(&mut ws, m, face, s.head)
                        .with_context(|| format!("frame {}", s.file.display()))?,
                );
            }
            let source = format!("{} (firmware pipeline)", blob_path.display());
            rows.push(row("decoder", weighting, engine, source, &test, &d, m.novelty.min_area));
            dets.push((("decoder", engine, weighting), d));
        }
    }
    for weighting in WEIGHTINGS {
        absent.push(Absent {
            model: "autoencoder".into(),
            weighting: weighting.into(),
            engine: "fixed".into(),
            reason: "the board runs decoders only: a model blob maps head angles to a face".into(),
        });
    }

    let find = |e: &str| {
        dets.iter()
            .find(|((m, en, w), _)| *m == "decoder" && *en == e && *w == "sigma")
            .map(|x| &x.1)
    };
    let quantized_agreement = match (find("float"), find("fixed")) {
        (Some(a), Some(b)) => {
            let agree = a.iter().zip(b).filter(|(x, y)| match (x.blob, y.blob) {
                (None, None) => true,
                (Some(p), Some(q)) => {
                    let (dx, dy) = (p.centroid[0] - q.centroid[0], p.centroid[1] - q.centroid[1]);
                    (dx * dx + dy * dy).sqrt() <= 1.0
                }
                _ => false,
            });
            Some(agree.count() as f64 / a.len() as f64)
        }
        _ => None,
    };
    let marked = test.iter().filter(|s| s.mark.is_some()).count();
    Ok(Report {
        data: ds.root.display().to_string(),
        blob: blob_path.display().to_string(),
        test_frames: test.len(),
        marked,
        unmarked: test.len() - marked,
        threshold: model.novelty.threshold,
        region: model.region,
        min_area: model.novelty.min_area,
        rows,
        absent,
        quantized_agreement,
        camera: *camera,
    })
}

/// The blob with every sigma set to 1.0 grey level (Q8.8 256) and its CRC redone: Sigma = I.
fn with_unit_sigma(bytes: &[u8], model: &Model) -> Result<Vec<u8>> {
    let start = model.sigma.0.as_ptr() as usize - bytes.as_ptr() as usize;
    let len = model.sigma.0.len();
    ensure!(start + len <= bytes.len(), "sigma table outside the blob");
    let mut out = bytes.to_vec();
    for c in out[start..start + len].chunks_exact_mut(2) {
        c.copy_from_slice(&256u16.to_le_bytes());
    }
    // And every pose cell's sigma table.
    for (_, sigma) in model.pose.iter().flat_map(|p| (0..p.grid.len()).filter_map(|k| p.tables(k))) {
        let start = sigma.0.as_ptr() as usize - bytes.as_ptr() as usize;
        ensure!(start + sigma.0.len() <= bytes.len(), "sigma table outside the blob");
        for c in out[start..start + sigma.0.len()].chunks_exact_mut(2) {
            c.copy_from_slice(&256u16.to_le_bytes());
        }
    }
    let crc = CRC32.checksum(&out[16..]);
    out[12..16].copy_from_slice(&crc.to_le_bytes());
    Ok(out)
}

fn row(
    model_name: &'static str,
    weighting: &'static str,
    engine: &'static str,
    source: String,
    test: &[&Sample],
    dets: &[Detection],
    min_area: u16,
) -> Row {
    let w = test.first().map_or(1, |s| s.face.crop.width as usize);
    let (mut overlap, mut precision, mut hits, mut marked) = (0f64, 0f64, 0usize, 0usize);
    let (mut alarms, mut unmarked) = (0usize, 0usize);
    let (mut img_scores, mut img_labels) = (Vec::new(), Vec::new());
    let (mut px_scores, mut px_labels) = (Vec::new(), Vec::new());
    let mut wrong = Vec::new();
    for (s, d) in test.iter().zip(dets) {
        let wrong_as = |what: &str| Wrong {
            file: s.file.display().to_string(),
            head: s.head,
            what: what.into(),
            blob: d.blob.map(|b| (b.area, b.centroid)),
            mark_pixels: s.mark.as_ref().map(|m| m.pixels_in_face() as u32),
            verdict: (d.light.verdict != msr_firmware::light::Verdict::Face).then(|| format!("{:?}", d.light.verdict)),
        };
        // The score is one of the f32 saliencies (or -inf), so the round trip is exact.
        let sal: Vec<f64> = d.saliency.iter().map(|&v| v as f64).collect();
        img_scores.push(detection_score(&sal, w, min_area) as f32);
        img_labels.push(s.mark.is_some());
        px_scores.extend_from_slice(&d.saliency);
        match &s.mark {
            None => {
                unmarked += 1;
                px_labels.extend(std::iter::repeat_n(false, d.saliency.len()));
                if d.blob.is_some() {
                    alarms += 1;
                    wrong.push(wrong_as("fired"));
                }
            }
            Some(mk) => {
                marked += 1;
                px_labels.extend_from_slice(&mk.face_mask);
                let on_mark = |fx: i64, fy: i64| -> bool {
                    let (cx, cy) = (fx - s.face.crop.x as i64, fy - s.face.crop.y as i64);
                    if mk.exact_mask {
                        cx >= 0
                            && cy >= 0
                            && (cx as usize) < w
                            && ((cy as usize) * w + cx as usize) < mk.face_mask.len()
                            && mk.face_mask[cy as usize * w + cx as usize]
                    } else {
                        mk.box_contains(fx as f32, fy as f32)
                    }
                };
                let (a_i, a_d) = d
                    .mask
                    .iter()
                    .zip(&mk.face_mask)
                    .fold((0u32, 0u32), |(i, o), (&sal, &mk)| {
                        (i + (sal && mk) as u32, o + (sal && !mk) as u32)
                    });
                if a_i + a_d > 0 {
                    precision += a_i as f64 / (a_i + a_d) as f64;
                }
                if let Some(b) = d.blob {
                    let [x0, y0, x1, y1] = b.box_xyxy;
                    let mut inter = 0u32;
                    for y in y0..=y1 {
                        for x in x0..=x1 {
                            inter += on_mark_pixel(s, w, x, y) as u32;
                        }
                    }
                    overlap += inter as f64 / mk.pixels.max(1) as f64;
                    if on_mark(b.centroid[0].round() as i64, b.centroid[1].round() as i64) {
                        hits += 1;
                    } else {
                        wrong.push(wrong_as("off the mark"));
                    }
                } else {
                    wrong.push(wrong_as("no blob"));
                }
            }
        }
    }
    let per = |v: f64, n: usize| if n > 0 { Some(v / n as f64) } else { None };
    Row {
        model: model_name.into(),
        weighting: weighting.into(),
        engine: engine.into(),
        overlap_over_mark_area: per(overlap, marked),
        precision_ai_over_ai_ad: per(precision, marked),
        hit_rate: per(hits as f64, marked),
        false_alarm_rate: per(alarms as f64, unmarked),
        image_auroc: auroc(&img_scores, &img_labels),
        pixel_auroc: auroc(&px_scores, &px_labels),
        source,
        wrong,
    }
}

/// Whether full-frame pixel (x, y) is a mark pixel inside the face crop.
fn on_mark_pixel(s: &Sample, w: usize, x: u32, y: u32) -> bool {
    let Some(mk) = &s.mark else { return false };
    let c = s.face.crop;
    if x < c.x || y < c.y || x >= c.x + c.width || y >= c.y + c.height {
        return false;
    }
    mk.face_mask[(y - c.y) as usize * w + (x - c.x) as usize]
}

/// A float model with the statistics and settings its rows use.
struct FloatModel {
    predictor: Box<dyn FacePredictor>,
    /// Grey levels.
    mu: Vec<f32>,
    /// Grey levels, floored as the model's calibration says.
    sigma: Vec<f32>,
    settings: Settings,
    region: Option<msr_shared::blob::PoseRegion>,
    /// Statistics per head-pose cell, floored like `sigma`.
    pose: Option<crate::detect::pipeline::PoseTables>,
    source: String,
}

/// `{name}.json` + `{name}.mpk` from `msr train` in `dir`: `Ok(None)` when there is none,
/// `Err(reason)` when there is one that cannot be used.
fn trained_model(
    dir: &Path,
    name: &str,
    face: (usize, usize),
    crop: crate::data::crop::CropMode,
) -> Result<Option<FloatModel>, String> {
    if !dir.join(format!("{name}.json")).is_file() {
        return Ok(None);
    }
    let m = crate::train::load(dir, name).map_err(|e| format!("{e:#}"))?;
    let info = m.info().map_err(|e| format!("{e:#}"))?.clone();
    let stats = crate::train::load_stats(dir, &info).map_err(|e| format!("{e:#}"))?;
    if (info.face_h, info.face_w) != face {
        return Err(format!(
            "trained {name} takes {}x{} faces, the dataset's are {}x{}",
            info.face_w, info.face_h, face.1, face.0
        ));
    }
    if info.crop != crop {
        return Err(format!(
            "trained {name} was trained on {} crops, the blob's faces are cropped {}",
            info.crop, crop
        ));
    }
    let floor = info.novelty.sigma_floor.max(1e-5);
    Ok(Some(FloatModel {
        predictor: Box::new(m),
        mu: stats.mu.iter().map(|&v| v as f32).collect(),
        sigma: stats.sigma.iter().map(|&v| v.max(floor) as f32).collect(),
        settings: info.novelty.settings(),
        region: info.novelty.region,
        pose: stats.pose.as_ref().map(|p| crate::detect::pipeline::PoseTables {
            grid: p.grid,
            mu: p.mu.iter().map(|m| m.iter().map(|&v| v as f32).collect()).collect(),
            sigma: p.sigma.iter().map(|s| s.iter().map(|&v| v.max(floor) as f32).collect()).collect(),
        }),
        source: format!(
            "{} (trained, float)",
            dir.join(format!("{name}.mpk")).display()
        ),
    }))
}

/// Refuses a manifest the blob was not imported from: the float rows would score another model
/// than the fixed-point rows. `msr import` puts the manifest's face size, its mean error (Q8.8)
/// and its template into the blob; all three must be the manifest's.
fn imported_from(model: &Model, blob_path: &Path, manifest: &Path) -> Result<()> {
    let p = crate::quant::import::Published::load(manifest)?;
    let not = |why: String| {
        anyhow::anyhow!(
            "--model {} was not imported from --manifest {} ({why}): the float rows would score another model; \
             give the manifest the blob was made from, or make the blob with msr import {} --out FILE",
            blob_path.display(),
            manifest.display(),
            manifest.display()
        )
    };
    let (h, w) = (p.decoder.face_h, p.decoder.face_w);
    if (model.face_h as usize, model.face_w as usize) != (h, w) {
        return Err(not(format!("faces of {}x{} and {w}x{h}", model.face_w, model.face_h)));
    }
    let differ = p.mu.iter().enumerate().filter(|&(i, &m)| i >= model.mu.len() || model.mu.get(i) != crate::quant::quantize::q8_8(m)).count();
    if differ > 0 {
        return Err(not(format!("their mean error differs at {differ} of {} pixels", p.mu.len())));
    }
    if let Some(t) = &model.template {
        if (t.w as u32, t.h as u32) != p.template.dimensions() || t.pixels != p.template.as_raw().as_slice() {
            return Err(not("their face templates differ".into()));
        }
    }
    Ok(())
}

/// The published float decoder with its float64 statistics (sigma + 1e-5, as the published code)
/// and its novelty settings.
fn published_float_decoder(manifest: &Path) -> Result<FloatModel> {
    let p = crate::quant::import::Published::load(manifest)?;
    let (h, w) = (p.decoder.face_h, p.decoder.face_w);
    ensure!(p.mu.len() == h * w, "statistics do not match the face");
    Ok(FloatModel {
        mu: p.mu.iter().map(|&v| v as f32).collect(),
        sigma: p.sigma.iter().map(|&v| (v + 1e-5) as f32).collect(),
        settings: Settings {
            threshold: p.threshold,
            normalisation: msr_shared::blob::Normalisation::StdDev,
            sided: p.sided,
            min_area: p.min_area,
            merge: msr_shared::blob::Merge::OFF,
        },
        region: None,
        pose: None,
        source: format!("{} (published float decoder)", manifest.display()),
        predictor: Box::new(p.decoder),
    })
}

/// The blob's dense decoder in float, with the blob's statistics and settings.
fn blob_float_decoder(model: &Model) -> Result<FloatModel, String> {
    let dec = dequantized_decoder(model).map_err(|e| format!("{e:#}"))?;
    let eng = float_engine_of(model);
    Ok(FloatModel {
        predictor: Box::new(dec),
        mu: eng.mu,
        sigma: eng.sigma,
        settings: eng.settings,
        region: eng.region,
        pose: eng.pose,
        source: "blob decoder dequantized to float (no trained decoder next to the blob)".into(),
    })
}

/// The report as markdown: the conditions, the table, the quantized agreement, the absent rows
/// and where each row's model came from.
pub fn markdown(r: &Report) -> String {
    let f = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{x:.3}"));
    let region = r.region.map_or(String::new(), |g| {
        format!(
            " (within {:.2} deg of head ({:.2}, {:.2}) deg: threshold {}, merge margin {} fragment {})",
            g.radius.to_degrees(),
            g.centre[0].to_degrees(),
            g.centre[1].to_degrees(),
            g.threshold,
            g.merge.margin,
            g.merge.fragment
        )
    });
    let mut s = format!(
        "Test split of {}: {} frames ({} marked, {} unmarked); threshold {}{region}, min area {}\n\
         Camera: {}\n\n",
        r.data, r.test_frames, r.marked, r.unmarked, r.threshold, r.min_area, r.camera
    );
    s += "| model | weighting | engine | overlap/mark | a_i/(a_i+a_d) | hit rate | false alarms | image AUROC | pixel AUROC |\n";
    s += "|---|---|---|---|---|---|---|---|---|\n";
    for x in &r.rows {
        s += &format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
            x.model,
            x.weighting,
            x.engine,
            f(x.overlap_over_mark_area),
            f(x.precision_ai_over_ai_ad),
            f(x.hit_rate),
            f(x.false_alarm_rate),
            f(x.image_auroc),
            f(x.pixel_auroc)
        );
    }
    s += &format!(
        "\nQuantized agreement (decoder, sigma, float vs fixed): {}\n",
        f(r.quantized_agreement)
    );
    if !r.absent.is_empty() {
        s += "\nAbsent rows:\n";
        for a in &r.absent {
            s += &format!(
                "- {} / {} / {}: {}\n",
                a.model, a.weighting, a.engine, a.reason
            );
        }
    }
    for x in &r.rows {
        s += &format!(
            "\n{} / {} / {}: {}",
            x.model, x.weighting, x.engine, x.source
        );
    }
    s.push('\n');
    s
}

#[cfg(test)]
mod range_tests {
    use super::*;

    /// Limited range as BT.601 codes luma (`16 + 219 E'`): black at 16, white at 235, the order
    /// of the levels kept; full range leaves the frame as it is.
    #[test]
    fn limited_range_codes_black_at_16_and_white_at_235() {
        let mut g: Vec<u8> = (0..=255).collect();
        code_range(&mut g, Range::Limited);
        assert_eq!((g[0], g[128], g[255]), (16, 126, 235));
        assert!(g.windows(2).all(|w| w[0] <= w[1]));
        let mut f: Vec<u8> = (0..=255).collect();
        code_range(&mut f, Range::Full);
        assert_eq!(f, (0..=255).collect::<Vec<u8>>());
    }

    /// The report states the conditions: in words for the table, by field in JSON.
    #[test]
    fn the_camera_is_stated_in_words_and_in_json() {
        assert_eq!(Camera::default().to_string(), "as recorded");
        let c = Camera { imperfect: Imperfections::NONE.with_gamma(0.8).with_jpeg(Some(50)), range: Range::Limited };
        assert_eq!(c.to_string(), "tone curve gamma 0.8, JPEG quality 50, limited range (16..=235)");
        let v = serde_json::to_value(c).unwrap();
        assert_eq!((v["imperfect"]["gamma"].as_f64(), v["imperfect"]["jpeg"].as_u64(), v["range"].as_str()), (Some(0.800000011920929), Some(50), Some("limited")));
        assert_eq!(serde_json::from_value::<Camera>(v).unwrap(), c);
    }
}
