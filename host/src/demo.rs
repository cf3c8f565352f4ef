//! The demo: from nothing to a report: dataset, training, reach, quantization, evaluation,
//! episodes, the real-frame check, a benchmark, `report.json` ([`DemoReport`]) and `index.html`.
//! `DemoConfig` in, `DemoReport` out; the command line makes the [`DemoConfig`] from its flags.
//!
//! Every step calls the other modules' library functions; each prints a progress line with its
//! time. What the demo does differently from the paper's full protocol, and why, is printed and
//! stored in `report.json` under `notes`.
use crate::episode::{self, Backend, EpisodeConfig};
use crate::train::{self, ModelKind};
use anyhow::{Context, Result};
use msr_sim::Robot;
use crate::data::crop::CropMode;
use crate::episode::ServoBus;
use crate::episode::Scene;
use crate::report::{DemoReport, MirrorTestReport, RealCheck, SceneReport, SelfGateReport, Training};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What the demo makes and how much of it: `DemoConfig::new(out)` is `msr demo`'s defaults (the
/// red robot, the paper's 1300 frames and 50 epochs, 40 trials, 5 of them under QEMU, the
/// Dynamixel bus, the error pooled over 5 x 5 with statistics per cell of a 3 x 3 head-pose grid,
/// a self gate calibrated for the robot in the model, as `msr quantize` attaches one).
#[derive(burn::config::Config, Debug)]
pub struct DemoConfig {
    /// Output folder.
    pub out: PathBuf,
    /// The sim robot the demo trains and tests.
    #[config(default = "Robot::Red")]
    pub robot: Robot,
    /// Face crop of the trained models: sub-pixel, or pixel (the published code).
    #[config(default = "CropMode::Subpixel")]
    pub crop: CropMode,
    /// Frames rendered (the paper's 1300).
    #[config(default = 1300)]
    pub frames: usize,
    /// Training epochs (the paper's 50).
    #[config(default = 50)]
    pub epochs: usize,
    /// Mirror-test trials in-process.
    #[config(default = 40)]
    pub trials: usize,
    /// Of those, how many also run under QEMU when it is installed (capped at 90 s in all).
    #[config(default = 5)]
    pub qemu_trials: usize,
    /// Folder of real frames in the published layout (default `../shared/data/nao-red-real`).
    pub real: Option<PathBuf>,
    /// Seed of everything the demo draws (frames, marks, training, trials).
    #[config(default = 0)]
    pub seed: u64,
    /// The servo bus of the episodes.
    #[config(default = "ServoBus::Dynamixel")]
    pub servo_bus: ServoBus,
    /// Trials in each scene (mirror, another robot, a delayed picture) with a self gate
    /// calibrated on the spot (0: none).
    #[config(default = 6)]
    pub gate_trials: usize,
    /// The error's pooling radius of both models (`TrainConfig::pool`; 0: per pixel, the paper).
    #[config(default = "train::calibrate::DEFAULT_POOL")]
    pub pool: u8,
    /// Cells per angle of the head-pose grid the error statistics are measured over
    /// (`TrainConfig::pose_bins`; 0: one set for all poses, the paper).
    #[config(default = "train::calibrate::DEFAULT_POSE_BINS")]
    pub pose_bins: u8,
    /// The model carries a self gate calibrated for `robot` (`train::self_gate`), as `msr
    /// quantize`'s does; `false`: a confirmed mark is reached at once, as the paper.
    #[config(default = true)]
    pub self_gate: bool,
    /// The model carries the face's colour (`train::chroma`), as `msr quantize`'s does;
    /// `false`: a grey model, as the paper.
    #[config(default = true)]
    pub colour: bool,
    /// How the dataset is lit (`msr_sim::light::LightMode`): by default half the training
    /// frames each under a light of its own, the test frames under the fixed light.
    #[config(default = "msr_sim::light::LightMode::VariedTrain")]
    pub light: msr_sim::light::LightMode,
}

struct Progress {
    t0: Instant,
    step: Instant,
    timings: BTreeMap<String, f64>,
}

impl Progress {
    fn start(&mut self, what: &str) {
        eprintln!("[{:>6.1} s] {what} ...", self.t0.elapsed().as_secs_f64());
        self.step = Instant::now();
    }
    fn done(&mut self, key: &str, detail: &str) {
        let s = self.step.elapsed().as_secs_f64();
        self.timings.insert(key.into(), (s * 100.0).round() / 100.0);
        eprintln!(
            "[{:>6.1} s]   {detail} ({s:.1} s)",
            self.t0.elapsed().as_secs_f64()
        );
    }
}

fn train_config(data: &Path, out: &Path, model: ModelKind, a: &DemoConfig) -> train::TrainConfig {
    train::TrainConfig::new(data.to_path_buf(), out.to_path_buf())
        .with_model(model)
        .with_crop(a.crop)
        .with_epochs(a.epochs)
        .with_seed(a.seed)
        .with_pool(a.pool)
        .with_pose_bins(a.pose_bins)
        .with_light_copies(light_copies(a.light))
        .with_quiet(true)
}

/// Light copies in the statistics only for a dataset under the one fixed light, as a recording
/// is (`train::light_copies`): the demo's other lights are rendered, which is better.
fn light_copies(light: msr_sim::light::LightMode) -> u8 {
    match light {
        msr_sim::light::LightMode::Fixed => train::light_copies::LightCopies::DEFAULT.copies,
        _ => 0,
    }
}

/// Rewrites `index.html` from an earlier run's `report.json`, `model.msrm` and dataset in `out`.
pub fn rewrite_html(out: &Path) -> Result<()> {
    let report: DemoReport = serde_json::from_slice(
        &std::fs::read(out.join("report.json")).context("report.json of an earlier run")?,
    )
    .context("report.json of an earlier run")?;
    let blob = std::fs::read(out.join("model.msrm")).context("model.msrm of an earlier run")?;
    crate::report::write_html(out, &report, &blob, &out.join("dataset"))
}

/// Runs the demo into `a.out` (see the module doc) and returns what it wrote to `report.json`.
pub fn run(a: &DemoConfig) -> Result<DemoReport> {
    let out = a.out.clone();
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let mut p = Progress {
        t0: Instant::now(),
        step: Instant::now(),
        timings: Default::default(),
    };
    let mut notes: Vec<String> = Vec::new();

    // 1. Dataset.
    p.start(&format!(
        "1/8 rendering the {} robot's dataset ({} frames, head angles within +-5 deg)",
        a.robot, a.frames
    ));
    let data = out.join("dataset");
    let mut dcfg = msr_sim::dataset::DatasetConfig::paper(a.robot, a.seed);
    dcfg.count = a.frames;
    dcfg.light = a.light;
    let index = msr_sim::dataset::write_dataset(&dcfg, &data)?;
    p.done(
        "dataset_s",
        &format!("{} frames in {}", index.frames.len(), data.display()),
    );

    // 2. Decoder and autoencoder, calibrated.
    let models = out.join("models");
    if a.crop == crate::data::crop::CropMode::Subpixel {
        notes.push(
            "Face crops at sub-pixel precision (`crop::CropMode::Subpixel`), not the published whole-pixel crop: the \
             template match's peak is refined by a parabola and the face resampled bilinearly, so that it does not \
             jump by a pixel between neighbouring head poses. `--crop pixel` gives the published crop."
                .into(),
        );
    }
    p.start(&format!("2/8 training the decoder ({} epochs, Adam lr 0.005 halved every 10, batch 128) and calibrating", a.epochs));
    train::run(train_config(&data, &models, ModelKind::Decoder, a))?;
    let max_head = dcfg.max_head_angle as f32;
    let choice = train::policy::apply(&models, "decoder", a.robot, max_head, a.seed)?;
    notes.push(novelty_note(&choice));
    let dec_info = train::load(&models, "decoder")?.info()?.clone();
    p.done(
        "train_decoder_s",
        &format!(
            "decoder test MSE {:.4}; {}",
            dec_info.final_test_mse,
            novelty_line(&dec_info.novelty)
        ),
    );
    p.start("   training the autoencoder (2-d code, same decoder)");
    train::run(train_config(&data, &models, ModelKind::Autoencoder, a))?;
    train::policy::apply(&models, "autoencoder", a.robot, max_head, a.seed)?;
    let ae_info = train::load(&models, "autoencoder")?.info()?.clone();
    p.done(
        "train_autoencoder_s",
        &format!("autoencoder test MSE {:.4}", ae_info.final_test_mse),
    );

    // 3. Reach.
    p.start("3/8 reach pairs by the sim's IK (70, as the published robot's) and the 2-10-5 reach network");
    let reach = crate::quant::model_blob::train_sim_reach(70, a.seed)?;
    let (xs, ys) = crate::quant::model_blob::sim_reach_pairs(70, a.seed);
    let rms = crate::train::reach::rms(&reach, &xs, &ys);
    p.done(
        "reach_s",
        &format!(
            "fit RMS per joint {:?} rad",
            rms.map(|v| (v * 1000.0).round() / 1000.0)
        ),
    );

    // 4. Quantize.
    p.start("4/8 quantizing to the fixed-point model blob");
    let blob = crate::quant::model_blob::blob_from_training(&models, "decoder", &reach)?;
    let (blob, colour) = if a.colour {
        crate::train::chroma::attach(&blob, &data).context("learning the face's colour (--no-colour leaves it out)")?
    } else {
        notes.push("The model is grey (`--no-colour`): a mark whose grey level matches the face's is not seen.".into());
        (blob, None)
    };
    // The same default as `msr quantize`: the model carries a gate calibrated for its robot, so
    // that the model the demo hands over does not reach for another robot's face.
    let (blob, gate_line) = if a.self_gate {
        let (gated, cal) = crate::train::self_gate::attach(&blob, a.robot, &crate::train::self_gate::GateCalibration::default())
            .context("calibrating the self gate (--no-self-gate leaves it out)")?;
        let g = &cal.gate;
        let mut line = format!(
            "; a self gate calibrated for the {} robot: gain {:.1} px/rad +- {:.1} %, rest {:.2} px, hold {:.2} px, level {:.2} px",
            a.robot,
            g.gain_px_per_rad,
            100.0 * g.gain_tol,
            g.rest_tol_px,
            g.hold_tol_px,
            g.level_tol_px
        );
        if let Some(t) = g.line_tol_px {
            line += &format!(", line {t:.2} px");
        }
        if let Some(j) = g.joint_tol {
            line += &format!(", joint {j:.3}");
        }
        (gated, line)
    } else {
        notes.push("The model has no self gate (`--no-self-gate`): a confirmed mark is reached at once, as the paper, even for another robot's face.".into());
        (blob, "; no self gate".to_string())
    };
    let model_path = out.join("model.msrm");
    crate::fsio::write(&model_path, &blob)?;
    p.done(
        "quantize_s",
        &format!("{} ({} bytes){gate_line}", model_path.display(), blob.len()),
    );

    // 5. Evaluation table.
    p.start("5/8 evaluating on the test split (decoder and autoencoder, sigma and none, float and fixed)");
    // The evaluation finds the trained float models next to the blob it is given.
    let beside = models.join("model.msrm");
    crate::fsio::write(&beside, &blob)?;
    let eval = crate::eval::evaluate(&beside, &data)?;
    p.done(
        "eval_s",
        &format!(
            "{} rows, float and fixed-point detections agree on {}",
            eval.rows.len(),
            match eval.quantized_agreement {
                Some(a) => format!("{:.1} % of the test frames", 100.0 * a),
                None => "(not compared)".into(),
            }
        ),
    );
    eprint!("{}", crate::eval::markdown(&eval));
    let colour = match colour {
        Some(calibration) => {
            p.start("   hue patches with the face's grey level on the unmarked test frames (colour, then grey alone)");
            let none = msr_sim::imperfect::Imperfections::NONE;
            let hue_marks = crate::eval::hue::hue_marks(&blob, &data, &none, a.seed)?;
            let grey = msr_shared::blob::set_chroma(&blob, None).map_err(|e| anyhow::anyhow!("{e}"))?;
            let hue_marks_grey = crate::eval::hue::hue_marks(&grey, &data, &none, a.seed)?;
            p.done(
                "hue_marks_s",
                &format!(
                    "found {} of {} (grey alone {}), {} of the {} with a strong hue; false alarms {} of {} frames; colour threshold {:.1} spreads over {} pose cells",
                    hue_marks.found, hue_marks.marks, hue_marks_grey.found, hue_marks.strong_found, hue_marks.strong, hue_marks.false_alarms, hue_marks.frames, calibration.threshold, calibration.cells
                ),
            );
            Some(crate::eval::hue::ColourCheck { calibration, hue_marks, hue_marks_grey })
        }
        None => None,
    };

    // 6. Episodes.
    notes.push(format!(
        "Episodes: {} in-process trials here (the 200-trial figures come from `msr mirror-test --trials 200`); each trial \
         judges the first second of the 5 s hold (the arm holds still for the rest).",
        a.trials
    ));
    p.start(&format!(
        "6/8 mirror-test episodes in-process ({} trials)",
        a.trials
    ));
    let mut cfg = EpisodeConfig::new(a.robot);
    cfg.servo_bus = a.servo_bus;
    let quiet = |_: &episode::Trial| {};
    let trials = episode::run_inproc(&blob, &cfg, a.trials, a.seed, &quiet)?;
    let inproc = episode::summarise(Backend::Inproc, a.robot, a.servo_bus, &trials);
    p.done("episodes_inproc_s", &inproc.to_string());
    let self_gate = if a.gate_trials > 0 {
        p.start(&format!(
            "   the self gate: {} trials in each scene (the mirror, another robot, a delayed picture), {}",
            a.gate_trials,
            if a.self_gate { "the model's gate" } else { "a gate calibrated on the spot" }
        ));
        let g = self_gate_episodes(&blob, &cfg, a)?;
        let line = g
            .scenes
            .iter()
            .map(|s| format!("{}: {} of {} trials reach", s.summary.scene, s.summary.reaches, s.summary.trials))
            .collect::<Vec<_>>()
            .join(", ");
        p.done("self_gate_s", &line);
        Some(g)
    } else {
        None
    };
    let mut mirror = MirrorTestReport { inproc, trials, qemu: None, qemu_matching_inproc: None, qemu_error: None };
    if let Some(why) = qemu_skipped(msr_sim::qemu::qemu_available(), &msr_sim::qemu::find_image(msr_sim::qemu::BOARD_IMAGE)) {
        eprintln!("   mirror-test episodes under QEMU {why}");
        mirror.qemu_error = Some(why);
    } else {
        p.start(&format!(
            "   mirror-test episodes under QEMU (the first {} of the same trials, at most {} s)",
            a.qemu_trials,
            QEMU_BUDGET.as_secs()
        ));
        match qemu_episodes(&blob, &cfg, &mirror.trials, a.qemu_trials, a.seed) {
            Ok((s, matching, note)) => {
                p.done("episodes_qemu_s", &format!("{s}; {note}"));
                mirror.qemu = Some(s);
                mirror.qemu_matching_inproc = Some(matching);
                notes.push(format!("QEMU episodes: {note}."));
            }
            Err(e) => {
                p.done("episodes_qemu_s", &format!("QEMU episodes failed: {e:#}"));
                mirror.qemu_error = Some(format!("{e:#}"));
            }
        }
    }

    // 7. Real frames.
    let real_dir = a
        .real
        .clone()
        .unwrap_or_else(|| PathBuf::from("../shared/data/nao-red-real"));
    let (real, real_skipped) = if real_dir.join(crate::data::MANIFEST_FILE).exists() {
        p.start(&format!(
            "7/8 the real-frame check with the imported published model ({})",
            real_dir.display()
        ));
        let r = real_check(&real_dir, &out)?;
        p.done(
            "real_s",
            &format!(
                "marks found on {}/{} marked frames, false alarms on {}/{} unmarked",
                r.hits, r.marked, r.false_alarms, r.unmarked
            ),
        );
        (Some(r), None)
    } else {
        eprintln!(
            "7/8 no real frames at {}: real-frame check skipped",
            real_dir.display()
        );
        (None, Some(format!("no {}", real_dir.display())))
    };

    // 8. Benchmark (the pipeline on this PC; `msr bench --backend qemu` gives instruction counts).
    p.start("8/8 benchmarking the pipeline on this PC with the demo's model");
    let bm = crate::bench::BenchModel {
        name: "demo".into(),
        source: model_path.display().to_string(),
        blob: blob.clone(),
    };
    let bench = crate::bench::bench_host(&bm, 5)?;
    p.done(
        "bench_s",
        &format!(
            "decoder {:.0} ns, whole frame {:.0} ns",
            bench["stages"]["decoder"].as_f64().unwrap_or(f64::NAN),
            bench["total_ns"].as_f64().unwrap_or(f64::NAN)
        ),
    );

    let total = p.t0.elapsed().as_secs_f64();
    p.timings.insert("total_s".into(), (total * 10.0).round() / 10.0);
    let report = DemoReport {
        robot: a.robot,
        eval,
        mirror_test: mirror,
        real,
        real_skipped,
        bench,
        timings: p.timings,
        training: Training { decoder: dec_info, autoencoder: ae_info },
        reach_fit_rms_rad: rms,
        self_gate,
        colour,
        notes,
    };
    crate::fsio::write(&out.join("report.json"), serde_json::to_vec_pretty(&report)?)?;
    crate::report::write_html(&out, &report, &blob, &data)?;
    eprintln!(
        "[{total:>6.1} s] wrote {0}/model.msrm, {0}/report.json, {0}/index.html",
        out.display()
    );
    Ok(report)
}

/// The chosen novelty settings in a few words.
fn novelty_line(n: &crate::train::calibrate::NoveltyParams) -> String {
    let error = match n.pool {
        0 => "per-pixel error".to_string(),
        r => format!("error pooled over {0} x {0}", 2 * r as u32 + 1),
    };
    let stats = match n.pose_grid {
        Some(g) => format!("statistics per cell of a {} x {} head-pose grid", g.bins[0], g.bins[1]),
        None => "one set of statistics".into(),
    };
    format!("{error}, {stats}; {}", novelty_thresholds(n))
}

/// The thresholds and merges of the chosen novelty settings, with the pose region's.
fn novelty_thresholds(n: &crate::train::calibrate::NoveltyParams) -> String {
    let merge = |m: msr_shared::blob::Merge| {
        if m.is_on() {
            format!("merge fragments of >= {} px within {} px", m.fragment, m.margin)
        } else {
            "no merge".into()
        }
    };
    let own = format!("threshold {:.2}, {}", n.threshold, merge(n.merge));
    match n.region {
        Some(g) => format!(
            "within {:.2} deg of the observe posture threshold {:.2}, {}; at other poses {own}",
            g.radius.to_degrees(),
            g.threshold,
            merge(g.merge)
        ),
        None => own,
    }
}

fn novelty_note(a: &train::policy::Applied) -> String {
    let said = |c: &Option<train::policy::Choice>, near: &Option<train::policy::Near>| match (c, near) {
        (Some(c), _) => format!(
            "threshold {:.2}, merge {:?} ({}: of the candidates under which none of {} unmarked frames fires at the \
             threshold or at threshold / {}, the one finding most of {} marked ones)",
            c.threshold, c.merge, c.poses, c.normal_frames, c.safety, c.marked_frames
        ),
        (None, Some(n)) => format!(
            "the paper's (no candidate kept all {} unmarked frames, each under a light of its own, quiet at the \
             threshold and at threshold / {}; the quietest, threshold {:.2} with merge {:?}, fired on {} of them and \
             found {} of {} marks)",
            n.normal_frames,
            train::policy::SAFETY,
            n.quietest.threshold,
            n.quietest.merge,
            n.quietest.normal_detections,
            n.quietest.hits,
            n.marked_frames
        ),
        (None, None) => "the paper's (no frames to calibrate on)".into(),
    };
    format!(
        "Novelty settings by the calibrated policy (`train::policy`), not the paper's fixed 4.59 and plain blobs: at any \
         head pose {}; near the observe posture, where the robot looks for marks, {}{}.",
        said(&a.general, &a.near[0]),
        said(&a.observe, &a.near[1]),
        if a.novelty.region.is_none() { " (the same: no pose region)" } else { "" }
    )
}

/// The demo's model with its self gate (one calibrated on the spot, `train::self_gate`, when the
/// model has none), a few trials in each scene: the gate must pass its own mirror image and
/// refuse the others.
fn self_gate_episodes(blob: &[u8], cfg: &EpisodeConfig, a: &DemoConfig) -> Result<SelfGateReport> {
    use crate::train::self_gate::{attach, GateCalibration};
    let own = msr_shared::blob::Model::parse(blob).ok().and_then(|m| m.self_gate);
    let (gated, g) = match own {
        Some(g) => (blob.to_vec(), crate::train::self_gate::SelfGateJson::from(&g)),
        None => {
            let (gated, cal) = attach(blob, a.robot, &GateCalibration::default())?;
            (gated, cal.gate)
        }
    };
    let mut scenes = Vec::new();
    for scene in [Scene::Mirror, Scene::Other, Scene::Delayed] {
        let mut c = cfg.clone();
        c.scene = scene;
        let trials = episode::run_inproc(&gated, &c, a.gate_trials, a.seed, &|_: &episode::Trial| {})?;
        let gain_ratios = trials.iter().flat_map(|t| t.gate.iter().filter_map(|g| g.gain_ratio)).collect();
        let summary = episode::summarise(Backend::Inproc, a.robot, a.servo_bus, &trials);
        scenes.push(SceneReport { summary, gain_ratios });
    }
    Ok(SelfGateReport {
        gain_tol: g.gain_tol,
        rest_tol_px: g.rest_tol_px,
        hold_tol_px: g.hold_tol_px,
        level_tol_px: g.level_tol_px,
        line_tol_px: g.line_tol_px,
        joint_tol: g.joint_tol,
        scenes,
    })
}

/// Why the demo runs no QEMU episodes, if it does not: QEMU missing, (on a fresh clone) the
/// board image not built yet, which is no failure, or the image older than its sources (after a
/// `git pull`: it would run other firmware than the in-process trials it is compared with).
fn qemu_skipped(qemu_available: bool, image: &Result<PathBuf>) -> Option<String> {
    use msr_sim::qemu::ImageError;
    match image {
        _ if !qemu_available => Some("skipped: qemu-system-arm is not installed (apt-get install qemu-system-arm)".into()),
        Ok(_) => None,
        Err(e) => Some(match e.downcast_ref::<ImageError>() {
            Some(ImageError::Stale { source, .. }) => format!(
                "skipped: the QEMU image is older than {}; run `cargo xtask images`",
                source.display()
            ),
            _ => "skipped: the QEMU image is not built; run `cargo xtask images`".into(),
        }),
    }
}

/// Wall time the QEMU episodes may take: a trial takes about 1.4 s on an idle machine (6 s of
/// the world's time in 1 ms ticks, each tick's bytes through the board image's pipe; the model
/// preloaded, not uploaded). The budget stops a demo on a machine far slower than that, or
/// busy, from waiting long for what the in-process trials already showed.
const QEMU_BUDGET: std::time::Duration = std::time::Duration::from_secs(90);

/// The first `n` trials again with the firmware image in QEMU (same seeds as `inproc`), until
/// [`QEMU_BUDGET`] is spent. Returns the summary, how many trials came out as in-process
/// (touched or not, false reach or not), and a line saying so.
fn qemu_episodes(
    blob: &[u8],
    cfg: &EpisodeConfig,
    inproc: &[episode::Trial],
    n: usize,
    seed: u64,
) -> Result<(episode::Summary, usize, String)> {
    let t0 = Instant::now();
    let model = msr_shared::blob::Model::parse(blob).map_err(|e| anyhow::anyhow!("model blob: {e}"))?;
    let cropper = crate::detect::cropper_of(&model)?;
    let renderer = msr_sim::render::Renderer::new(cfg.robot);
    let mut board = crate::episode::qemu::QemuBoard::start(blob)?;
    let start_s = board.start_s;
    let mut done = Vec::new();
    // A trial starts only if one as slow as the slowest so far still ends within the budget.
    let mut slowest = std::time::Duration::ZERO;
    for i in 0..n {
        if t0.elapsed() + slowest > QEMU_BUDGET {
            break;
        }
        let t = Instant::now();
        let camera = episode::Camera { renderer: &renderer, cropper: &cropper };
        done.push(board.trial(camera, cfg, i, episode::trial_seed(seed, i))?);
        slowest = slowest.max(t.elapsed());
    }
    board.finish()?;
    let matching = done
        .iter()
        .filter(|q| {
            inproc
                .iter()
                .find(|t| t.index == q.index)
                .is_some_and(|t| (t.touched, t.false_reach, t.latency_ms) == (q.touched, q.false_reach, q.latency_ms))
        })
        .count();
    let note = format!(
        "{} of {n} trials in {:.0} s (the model preloaded into the board's memory, checked by the board as an upload: QEMU running it after {start_s:.1} s), {matching} the same as in-process",
        done.len(),
        t0.elapsed().as_secs_f64()
    );
    Ok((episode::summarise(Backend::Qemu, cfg.robot, cfg.servo_bus, &done), matching, note))
}

/// The published model on the real frames: marks found with the centroid in the box, and
/// detections on unmarked frames.
pub fn real_check(real_dir: &Path, out: &Path) -> Result<RealCheck> {
    let manifest = real_dir.join(crate::data::MANIFEST_FILE);
    let published = crate::quant::import::Published::load(&manifest)?;
    let bytes = published
        .to_spec()?
        .to_bytes()
        .map_err(|e| anyhow::anyhow!("published blob: {e}"))?;
    crate::fsio::write(&out.join("published.msrm"), &bytes)?;
    let model = msr_shared::blob::Model::parse(&bytes)
        .map_err(|e| anyhow::anyhow!("published blob: {e}"))?;
    let ds = crate::data::Dataset::load(real_dir, crate::detect::crop_mode_of(&model))?;
    let (mut marked, mut hits, mut unmarked, mut false_alarms) = (0, 0, 0, 0);
    for s in &ds.samples {
        let d = crate::detect::fixed::detect(&model, &s.face, s.head)?;
        match &s.mark {
            Some(m) => {
                marked += 1;
                if d.blob
                    .as_ref()
                    .is_some_and(|b| m.box_contains(b.centroid[0] as f32, b.centroid[1] as f32))
                {
                    hits += 1;
                }
            }
            None => {
                unmarked += 1;
                if d.blob.is_some() {
                    false_alarms += 1;
                }
            }
        }
    }
    Ok(RealCheck { marked, hits, unmarked, false_alarms })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn qemu_episodes_are_skipped_not_failed_without_qemu_or_image() {
        let missing = msr_sim::qemu::find_image("no-such-image");
        let why = qemu_skipped(true, &missing).unwrap();
        assert_eq!(why, "skipped: the QEMU image is not built; run `cargo xtask images`");
        assert!(qemu_skipped(false, &missing).unwrap().starts_with("skipped: qemu-system-arm is not installed"));
        assert_eq!(qemu_skipped(true, &Ok(PathBuf::from("msr-qemu"))), None);
        let stale = Err(msr_sim::qemu::ImageError::Stale { image: "msr-qemu".into(), source: "firmware/src/lib.rs".into() }.into());
        assert_eq!(
            qemu_skipped(true, &stale).unwrap(),
            "skipped: the QEMU image is older than firmware/src/lib.rs; run `cargo xtask images`"
        );
    }
}
