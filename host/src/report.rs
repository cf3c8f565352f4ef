//! The demo's `index.html`: for a few test frames the frame, the crop, the predicted face, the
//! saliency, the binarised map and the detection; the loss curves; the tables; the reach poses.
//! Pictures are PNGs in `DIR/pictures/`, linked (not embedded) so the page stays small.
//!
//! The page is made from a [`DemoReport`] alone (and the files beside it), the struct `msr demo`
//! writes as `report.json`; `msr demo --html-only` reads it back.
use crate::data::crop;
use anyhow::{Context, Result};
use image::{imageops, Rgb, RgbImage};
use imageproc::drawing::{draw_cross_mut, draw_hollow_rect_mut};
use imageproc::rect::Rect;
use msr_shared::blob::Model;
use msr_sim::layout::{DatasetIndex, Split};
use crate::episode::{Summary, Trial};
use crate::train::ModelInfo;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

/// `report.json`: what `msr demo` found.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct DemoReport {
    /// The simulated robot the demo ran with.
    pub robot: msr_sim::Robot,
    /// The paper's table on the test split.
    pub eval: crate::eval::Report,
    /// The mirror-test episodes, in process and under QEMU.
    pub mirror_test: MirrorTestReport,
    /// The published model on the real frames; `None` when there were none (`real_skipped` says).
    pub real: Option<RealCheck>,
    /// Why the real frames were not checked (`None` when they were).
    pub real_skipped: Option<String>,
    /// `msr bench --backend host` for the demo's model, as that command prints it.
    pub bench: Value,
    /// Seconds per step (`dataset_s`, `train_decoder_s`, ...) and `total_s`.
    pub timings: BTreeMap<String, f64>,
    /// What the decoder's and the autoencoder's training reported.
    pub training: Training,
    /// The reach network's fit on its 70 sim pairs, per joint.
    pub reach_fit_rms_rad: [f64; 5],
    /// The self gate in the three scenes (`None`: not run).
    #[serde(default)]
    pub self_gate: Option<SelfGateReport>,
    /// The model's colour and the hue patches it finds (`None`: a grey model).
    #[serde(default)]
    pub colour: Option<crate::eval::hue::ColourCheck>,
    /// What the demo does differently from the paper's full protocol, and why.
    pub notes: Vec<String>,
}

/// The demo's model with a self gate calibrated on the spot, a few trials in each scene.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SelfGateReport {
    /// The gate passes a gain ratio (measured over calibrated) within `1 -+ gain_tol`.
    pub gain_tol: f32,
    /// Largest distance of the resting face from the probe's line, pixels.
    pub rest_tol_px: f32,
    /// Largest x range of the face while the head holds, pixels (0 in a report without it).
    #[serde(default)]
    pub hold_tol_px: f32,
    /// Largest vertical move of the face at a probe pose from its rest, pixels (0 in a report
    /// without it).
    #[serde(default)]
    pub level_tol_px: f32,
    /// The return stage's line tolerance, pixels (`None`: a two-stage gate, or a report without
    /// it).
    #[serde(default)]
    pub line_tol_px: Option<f32>,
    /// The joint bound (`None`: the box alone, or a report without it).
    #[serde(default)]
    pub joint_tol: Option<f32>,
    /// The trials in each scene.
    pub scenes: Vec<SceneReport>,
}

/// One scene's trials with the gate.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SceneReport {
    /// The scene's trials summed up.
    pub summary: Summary,
    /// Every decision's gain ratio, the statistic the gate tests.
    pub gain_ratios: Vec<f32>,
}

/// The two trained models' `{name}.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Training {
    /// The decoder's summary: head angles to the face.
    pub decoder: ModelInfo,
    /// The autoencoder's summary: a 2-d code, then the same decoder.
    pub autoencoder: ModelInfo,
}

/// The demo's mirror-test episodes.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct MirrorTestReport {
    /// The in-process trials summed up.
    pub inproc: Summary,
    /// The in-process trials one by one.
    pub trials: Vec<Trial>,
    /// The first trials again under QEMU.
    pub qemu: Option<Summary>,
    /// Of those, how many came out as in-process.
    pub qemu_matching_inproc: Option<usize>,
    /// Why there are no QEMU episodes.
    pub qemu_error: Option<String>,
}

/// The published model on the real frames: marks found (centroid in the box) and detections on
/// unmarked frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct RealCheck {
    /// Real frames with a mark.
    pub marked: usize,
    /// Marked frames whose detected blob has its centroid in the mark's box.
    pub hits: usize,
    /// Real frames without a mark.
    pub unmarked: usize,
    /// Unmarked frames with a detected blob.
    pub false_alarms: usize,
}

/// Crops are shown this many times larger.
const ZOOM: u32 = 3;

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

fn zoom(img: &RgbImage) -> RgbImage {
    imageops::resize(
        img,
        img.width() * ZOOM,
        img.height() * ZOOM,
        imageops::FilterType::Nearest,
    )
}

fn grey_rgb(w: u32, h: u32, px: impl Fn(u32, u32) -> u8) -> RgbImage {
    RgbImage::from_fn(w, h, |x, y| Rgb([px(x, y); 3]))
}

/// Saliency in threshold units as a heat map: black at 0, red at the threshold, yellow at 3x.
fn heat(v: f32) -> Rgb<u8> {
    let t = (v / 3.0).clamp(0.0, 1.0);
    let r = (t * 3.0).min(1.0);
    let g = ((t - 0.33) * 1.5).clamp(0.0, 1.0);
    Rgb([(r * 255.0) as u8, (g * 255.0) as u8, 0])
}

/// The strip of one test frame; returns the picture's file names.
fn frame_pictures(
    model: &Model,
    data: &Path,
    f: &msr_sim::layout::FrameRecord,
    i: usize,
    pics: &Path,
) -> Result<(Vec<String>, String)> {
    let frame = crop::load_grey(&data.join(&f.file))?;
    let rgb_frame = image::open(data.join(&f.file))
        .with_context(|| format!("frame {}", f.file))?
        .to_rgb8();
    // The detection as the board makes it: with the face's colour for a model with colour.
    let face = crate::detect::cropper_of(model)?.crop_colour(&frame, &rgb_frame)?;
    let head = [f.head_yaw as f32, f.head_pitch as f32];
    let d = crate::detect::fixed::detect(model, &face, head)?;
    let (w, h) = (face.crop.width, face.crop.height);
    let mut full = rgb_frame.clone();
    draw_hollow_rect_mut(
        &mut full,
        Rect::at(face.crop.x as i32, face.crop.y as i32).of_size(w, h),
        Rgb([40, 220, 40]),
    );
    if let Some(m) = &f.mark {
        let [x0, y0, x1, y1] = m.box_xyxy_inclusive;
        draw_hollow_rect_mut(
            &mut full,
            Rect::at(x0 as i32 - 1, y0 as i32 - 1).of_size(x1 - x0 + 3, y1 - y0 + 3),
            Rgb([60, 120, 255]),
        );
    }
    if let Some(b) = d.blob {
        let [x0, y0, x1, y1] = b.box_xyxy;
        draw_hollow_rect_mut(
            &mut full,
            Rect::at(x0 as i32, y0 as i32).of_size(x1 - x0 + 1, y1 - y0 + 1),
            Rgb([255, 40, 40]),
        );
        draw_cross_mut(
            &mut full,
            Rgb([255, 255, 0]),
            b.centroid[0].round() as i32,
            b.centroid[1].round() as i32,
        );
    }
    let crop_img = grey_rgb(w, h, |x, y| face.grey[(y * w + x) as usize]);
    let pred = grey_rgb(w, h, |x, y| {
        (d.predicted[(y * w + x) as usize] * 255.0)
            .round()
            .clamp(0.0, 255.0) as u8
    });
    let sal = RgbImage::from_fn(w, h, |x, y| heat(d.saliency[(y * w + x) as usize]));
    let mut bin = grey_rgb(
        w,
        h,
        |x, y| if d.mask[(y * w + x) as usize] { 255 } else { 0 },
    );
    if let Some(b) = d.blob {
        let [x0, y0, x1, y1] = b.box_xyxy;
        let (cx, cy) = (face.crop.x as i32, face.crop.y as i32);
        draw_hollow_rect_mut(
            &mut bin,
            Rect::at(x0 as i32 - cx, y0 as i32 - cy).of_size(x1 - x0 + 1, y1 - y0 + 1),
            Rgb([255, 40, 40]),
        );
    }
    let names = ["frame", "crop", "predicted", "saliency", "binarised"];
    let imgs = [full, zoom(&crop_img), zoom(&pred), zoom(&sal), zoom(&bin)];
    let mut files = Vec::new();
    for (n, img) in names.iter().zip(imgs) {
        let file = format!("test{i}_{n}.png");
        crate::fsio::write_with(&pics.join(&file), |tmp| Ok(img.save(tmp)?))?;
        files.push(format!("pictures/{file}"));
    }
    let truth = f.mark.as_ref().map_or("no mark".to_string(), |m| {
        format!("{} {} at box {:?}", m.colour, m.shape, m.box_xyxy_inclusive)
    });
    let found = d.blob.map_or("nothing found".to_string(), |b| {
        let hit = f.mark.as_ref().is_some_and(|m| {
            let [x0, y0, x1, y1] = m.box_xyxy_inclusive;
            (x0 as f64..=x1 as f64).contains(&b.centroid[0])
                && (y0 as f64..=y1 as f64).contains(&b.centroid[1])
        });
        format!(
            "blob of {} px at ({:.1}, {:.1}){}",
            b.area,
            b.centroid[0],
            b.centroid[1],
            if hit {
                ", on the mark"
            } else {
                ", off the mark"
            }
        )
    });
    let caption = format!(
        "{} - head ({:.3}, {:.3}) rad - truth: {truth} - detection: {found}",
        f.file, f.head_yaw, f.head_pitch
    );
    Ok((files, caption))
}

/// Renders the robot at a trial's reach posture, with its mark, as the camera sees it.
fn reach_picture(robot: msr_sim::Robot, q: [f32; 5], file: &Path) -> Result<()> {
    let r = msr_sim::render::Renderer::new(robot);
    let q64 = q.map(f64::from);
    let mut pose = msr_sim::body::BodyPose::head(q64[0], q64[1]);
    pose.left_arm = msr_sim::kin::LeftArm::from_reach(&q64);
    let img = r
        .render(&pose, None, &msr_sim::render::Variation::CLEAN)
        .rgb;
    crate::fsio::write_with(file, |tmp| Ok(img.save(tmp)?))
}

fn num(v: &Value) -> String {
    match v {
        Value::Null => "-".into(),
        Value::Number(n) => n.as_f64().map_or(n.to_string(), |f| {
            if f.fract() == 0.0 && f.abs() < 1e9 {
                format!("{f}")
            } else {
                format!("{f:.3}")
            }
        }),
        Value::String(s) => esc(s),
        other => esc(&other.to_string()),
    }
}

/// A column name as a header: underscores become spaces so that a narrow column can wrap.
fn header(c: &str) -> String {
    esc(&c.replace('_', " "))
}

/// A table of `rows` by `cols`. A wide table of few rows (a summary per backend) is drawn
/// transposed, one row a field, so that it fits the page.
fn table(rows: &[Value], cols: &[&str]) -> String {
    let mut s = String::from("<table>");
    if cols.len() > 10 && rows.len() <= 4 {
        for c in cols {
            let _ = write!(s, "<tr><th>{}</th>", header(c));
            for r in rows {
                let _ = write!(s, "<td>{}</td>", num(&r[*c]));
            }
            s.push_str("</tr>");
        }
        s.push_str("</table>");
        return s;
    }
    s.push_str("<tr>");
    for c in cols {
        let _ = write!(s, "<th>{}</th>", header(c));
    }
    s.push_str("</tr>");
    for r in rows {
        s.push_str("<tr>");
        for c in cols {
            let _ = write!(s, "<td>{}</td>", num(&r[*c]));
        }
        s.push_str("</tr>");
    }
    s.push_str("</table>");
    s
}

fn kv(v: &Value) -> String {
    let mut s = String::from("<table>");
    if let Value::Object(m) = v {
        for (k, x) in m {
            if !x.is_object() && !x.is_array() {
                let _ = write!(s, "<tr><th>{}</th><td>{}</td></tr>", esc(k), num(x));
            }
        }
    }
    s.push_str("</table>");
    s
}

/// The self gate's scenes: a table, and the gain ratio of every decision per scene against the
/// pass band (an inline SVG strip plot).
fn self_gate_section(h: &mut String, g: &SelfGateReport) {
    let _ = write!(h, "<h2>The self gate: is it me?</h2><p>Before a confirmed mark starts a reach, the board turns its head a few degrees each way and checks that the face in the frame follows with its own mirror image's gain. The demo's model with its gate (calibrated for the robot when the model is made), in three scenes: its own mirror image, another robot of the same look where the image would be (holding still or babbling its head), and its own image through a video delay of 0.3-2 s. Only the mirror may reach.</p>");
    let rows: Vec<Value> = g.scenes.iter().map(|s| value(&s.summary)).collect();
    h.push_str(&table(
        &rows,
        &["scene", "trials", "marked_trials", "touched", "reaches", "gate_passes", "gate_rejects", "gate_undecided", "latency_ms_median"],
    ));
    let all: Vec<f32> = g.scenes.iter().flat_map(|s| s.gain_ratios.iter().copied()).collect();
    let (lo, hi) = all
        .iter()
        .fold((1.0 - 2.0 * g.gain_tol, 1.0 + 2.0 * g.gain_tol), |(l, u), &r| (l.min(r), u.max(r)));
    let (lo, hi) = (lo - 0.02, hi + 0.02);
    let (w, row, left) = (600.0f32, 28.0f32, 90.0f32);
    let x = |r: f32| left + (r - lo) / (hi - lo) * (w - left - 10.0);
    let height = row * g.scenes.len() as f32 + 30.0;
    let _ = write!(h, "<svg width={w} height={height} style=\"font:12px sans-serif\"><rect x={:.1} y=0 width={:.1} height={:.1} fill=\"#dfd\"/>",
        x(1.0 - g.gain_tol), x(1.0 + g.gain_tol) - x(1.0 - g.gain_tol), row * g.scenes.len() as f32);
    for (i, s) in g.scenes.iter().enumerate() {
        let y = row * i as f32 + row / 2.0;
        let _ = write!(h, "<text x=4 y={:.1}>{}</text>", y + 4.0, esc(&s.summary.scene));
        for &r in &s.gain_ratios {
            let _ = write!(h, "<circle cx={:.1} cy={y:.1} r=3 fill=\"#c22\" fill-opacity=0.6/>", x(r));
        }
    }
    let axis = row * g.scenes.len() as f32 + 14.0;
    for t in [lo, 1.0 - g.gain_tol, 1.0, 1.0 + g.gain_tol, hi] {
        let _ = write!(h, "<text x={:.1} y={axis:.1} text-anchor=middle>{t:.2}</text>", x(t));
    }
    let _ = write!(h, "</svg><p class=cap>Gain ratio (the face's shift per radian of head yaw over the calibrated one) of every decision, per scene; green: the band the gate passes (1 &plusmn; {:.3}).</p>", g.gain_tol);
    if g.hold_tol_px > 0.0 {
        let _ = write!(h, "<p>Besides the gain, a pass needs the resting face within {:.2} px of the line between the probe's poses, the face's x within {:.2} px while the head holds still, and its y within {:.2} px of its rest at each pose (each calibrated from the own image's spread).</p>", g.rest_tol_px, g.hold_tol_px, g.level_tol_px);
        if let Some(t) = g.line_tol_px {
            let _ = write!(h, "<p>The probe ends back at the resting yaw, where the face must lie within {t:.2} px of the probe's line.</p>");
        }
        if let Some(j) = g.joint_tol {
            let _ = write!(h, "<p>And the statistics' squared shares of their tolerances must sum to at most {j:.3}: the own image comes near one tolerance at a time, a stranger that gets inside them by luck near several.</p>");
        }
    }
}

fn value<T: Serialize>(x: &T) -> Value {
    serde_json::to_value(x).unwrap_or(Value::Null)
}

/// Writes `index.html` and its pictures into `out` from `report`, the demo's model blob and its
/// dataset folder `data`.
pub fn write_html(out: &Path, report: &DemoReport, blob: &[u8], data: &Path) -> Result<()> {
    let pics = out.join("pictures");
    std::fs::create_dir_all(&pics)?;
    let model = Model::parse(blob).map_err(|e| anyhow::anyhow!("model blob: {e}"))?;
    let index: DatasetIndex =
        serde_json::from_slice(&std::fs::read(data.join(msr_sim::layout::INDEX_FILE))?)?;
    let robot = report.robot;

    let mut h = String::new();
    let _ = write!(
        h,
        "<!doctype html><html><head><meta charset=utf-8><meta name=viewport content=\"width=device-width\"><title>msr demo: {robot}</title><style>\
         body{{font-family:sans-serif;margin:2em auto;padding:0 1em;max-width:1200px;color:#222}} \
         table{{border-collapse:collapse;margin:.5em 0;max-width:100%;font-size:90%}} \
         td,th{{border:1px solid #bbb;padding:3px 6px;text-align:right;overflow-wrap:anywhere}} th{{background:#eee}} \
         .strip{{display:grid;grid-template-columns:320fr repeat(4,225fr);gap:6px;align-items:start}} \
         .strip figure{{margin:0;min-width:0}} .strip img{{width:100%;height:auto;image-rendering:pixelated;display:block}} \
         figure{{display:inline-block;margin:4px;max-width:100%}} img{{max-width:100%;height:auto}} \
         .plots{{display:grid;grid-template-columns:1fr 1fr;gap:8px}} .plots figure{{margin:0}} .plots img{{width:100%}} \
         figcaption{{font-size:80%;color:#555}} .cap{{font-size:85%;color:#444;margin-bottom:1.2em}}</style></head><body>"
    );
    let _ = write!(h, "<h1>Mirror mark test: the {robot} robot</h1><p>Everything below was made by <code>msr demo</code> from nothing: a rendered dataset, the decoder trained and calibrated, the reach network trained on the sim's IK pairs, the fixed-point blob, the paper's table, mirror-test episodes through the emulated links, and the published model on the real frames.</p>");

    // Test frames.
    let _ = write!(h, "<h2>Test frames through the board's pipeline</h2><p>Left to right: the camera frame (green: face crop, blue: the mark's true box, red: detected blob, yellow: its centroid), the crop, the face the decoder predicts for the head angles the servos report, the saliency (red at the threshold, yellow at 3x), the binarised map with the winning blob.</p>");
    let test: Vec<&msr_sim::layout::FrameRecord> =
        index.split(Split::Test).map(|(_, f)| f).take(4).collect();
    for (i, f) in test.iter().enumerate() {
        match frame_pictures(&model, data, f, i, &pics) {
            Ok((files, cap)) => {
                h.push_str("<div class=strip>");
                for (file, name) in
                    files
                        .iter()
                        .zip(["frame", "crop", "predicted", "saliency", "binarised"])
                {
                    let _ = write!(h, "<figure><img src=\"{file}\" alt=\"{name}\"><figcaption>{name}</figcaption></figure>");
                }
                let _ = write!(h, "</div><div class=cap>{}</div>", esc(&cap));
            }
            Err(e) => {
                let _ = write!(
                    h,
                    "<p>frame {}: {}</p>",
                    esc(&f.file),
                    esc(&format!("{e:#}"))
                );
            }
        }
    }

    // Loss curves.
    let _ = write!(h, "<h2>Training</h2><div class=plots>");
    for name in ["decoder", "autoencoder"] {
        let src = out.join("models").join(format!("{name}_loss.png"));
        if src.exists() {
            let _ = write!(h, "<figure><img src=\"models/{name}_loss.png\" alt=\"{name} loss\"><figcaption>{name}: loss per epoch</figcaption></figure>");
        }
    }
    h.push_str("</div>");
    let tr = &report.training;
    let rows: Vec<Value> = [("decoder", &tr.decoder), ("autoencoder", &tr.autoencoder)]
        .iter()
        .map(|(n, t)| {
            serde_json::json!({"model": n, "arch": t.arch, "train frames": t.train_frames, "epochs": t.hyper.epochs,
                "final train MSE": t.final_train_mse, "final test MSE": t.final_test_mse, "training s": t.training_seconds})
        })
        .collect();
    h.push_str(&table(
        &rows,
        &[
            "model",
            "arch",
            "train frames",
            "epochs",
            "final train MSE",
            "final test MSE",
            "training s",
        ],
    ));

    // Tables.
    let ev = &report.eval;
    let region = match &ev.region {
        Some(g) => format!(
            "; near the observe posture (head angles within {} rad of {:?}) threshold {}, merge {}",
            g.radius, g.centre, g.threshold, esc(&value(&g.merge).to_string())
        ),
        None => String::new(),
    };
    let _ = write!(h, "<h2>Detection on the test split (the paper's table)</h2><p>{} test frames ({} marked, {} unmarked), threshold {}{region}, min area {}. Quantized agreement (float vs fixed decoder, sigma weighting): {}.</p>",
        ev.test_frames, ev.marked, ev.unmarked, ev.threshold, ev.min_area, num(&value(&ev.quantized_agreement)));
    let rows: Vec<Value> = ev.rows.iter().map(value).collect();
    h.push_str(&table(
        &rows,
        &[
            "model",
            "weighting",
            "engine",
            "overlap_over_mark_area",
            "precision_ai_over_ai_ad",
            "hit_rate",
            "false_alarm_rate",
            "image_auroc",
            "pixel_auroc",
        ],
    ));
    if !ev.absent.is_empty() {
        let abs: Vec<Value> = ev.absent.iter().map(value).collect();
        h.push_str(&table(&abs, &["model", "weighting", "engine", "reason"]));
    }

    let mt = &report.mirror_test;
    let _ = write!(h, "<h2>Mirror-test episodes</h2><p>Each trial: the robot at home, a mark appears at 0.4 s (none in 20 % of trials), frames stream over the emulated 921600-baud host link, the board detects, confirms (3 of 5 frames) and reaches at speed fraction 0.1; the sim judges by forward kinematics (fingertip within 20 mm of the mark's point over 1 s of the hold).</p>");
    let bus = mt.inproc.servo_bus.as_str();
    let _ = write!(h, "<p>Servo bus: <b>{bus}</b>{}</p>", if bus == "dynamixel" { " (Dynamixel Protocol 2.0 at 1 Mbaud: the board is the bus master of emulated XM430-W350 servos, with one Sync Write of goals and one Sync Read of positions every 10 ms)" } else { " (the project's framed servo messages)" });
    let sums: Vec<Value> = std::iter::once(&mt.inproc).chain(&mt.qemu).map(value).collect();
    h.push_str(&table(
        &sums,
        &[
            "backend",
            "robot",
            "trials",
            "marked_trials",
            "touched",
            "touch_rate",
            "no_mark_trials",
            "false_reaches",
            "median_touch_error_mm",
            "latency_ms_median",
            "limit_violations",
            "crc_errors",
            "resyncs",
            "watchdog_trips",
            "goodput_bytes_per_s",
            "retransmissions",
            "frames_superseded",
        ],
    ));
    if let Some(e) = &mt.qemu_error {
        let _ = write!(h, "<p>QEMU: {}</p>", esc(e));
    }
    let misses: Vec<Value> = mt
        .trials
        .iter()
        .filter(|t| t.mark.is_some() && !t.touched || t.false_reach)
        .map(value)
        .collect();
    if !misses.is_empty() {
        let _ = write!(h, "<p>Trials that did not touch (and why):</p>");
        h.push_str(&table(
            &misses,
            &["index", "mark", "reached", "false_reach", "failure"],
        ));
    }

    // Reach poses.
    let _ = write!(h, "<h2>Reach poses</h2><p>The robot at the posture the board streamed, as its camera sees it in the mirror, for a few touched trials.</p>");
    for t in mt.trials.iter().filter(|t| t.touched).take(4) {
        let Some(q) = t.reach_target else {
            continue;
        };
        let file = format!("reach{}.png", t.index);
        if reach_picture(robot, q, &pics.join(&file)).is_ok() {
            let mm = t.touch_error_mm.map_or("-".into(), |d| format!("{d:.1}"));
            let _ = write!(h, "<figure><img src=\"pictures/{file}\"><figcaption>trial {}: {} - {mm} mm<br>[{:.2}, {:.2}, {:.2}, {:.2}, {:.2}] rad</figcaption></figure>",
                t.index, esc(t.mark.as_deref().unwrap_or("-")), q[0], q[1], q[2], q[3], q[4]);
        }
    }

    if let Some(g) = &report.self_gate {
        self_gate_section(&mut h, g);
    }

    let _ = write!(
        h,
        "<h2>The published model on the real frames</h2>{}",
        match (&report.real, &report.real_skipped) {
            (Some(r), _) => kv(&value(r)),
            (None, why) => format!("<p>Skipped: {}</p>", esc(why.as_deref().unwrap_or("no real frames"))),
        }
    );
    let _ = write!(
        h,
        "<h2>The pipeline's cost on this PC</h2>{}",
        kv(&report.bench)
    );
    if let Some(st) = report.bench["stages"].as_object() {
        let _ = write!(
            h,
            "<p>Stages (ns): {}</p>",
            st.iter()
                .map(|(k, v)| format!("{k} {}", num(v)))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    let _ = write!(h, "<h2>Timings (s)</h2>{}", kv(&value(&report.timings)));
    if !report.notes.is_empty() {
        h.push_str("<h2>Notes</h2><ul>");
        for x in &report.notes {
            let _ = write!(h, "<li>{}</li>", esc(x));
        }
        h.push_str("</ul>");
    }
    h.push_str("</body></html>\n");
    crate::fsio::write(&out.join("index.html"), h)?;
    Ok(())
}
