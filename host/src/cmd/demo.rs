//! `msr demo`: from nothing to a report: dataset, training, reach, quantization, evaluation,
//! episodes, the real-frame check, a benchmark, `report.json` and `index.html`.
//!
//! Every step calls the other modules' library functions; each prints a progress line with its
//! time. What the demo does differently from the paper's full protocol, and why, is printed and
//! stored in `report.json` under `notes`.
use crate::episode::{self, Backend, EpisodeConfig};
use crate::models::ArchKind;
use crate::train::{self, DeviceArg, ModelKind, NormArg};
use anyhow::{Context, Result};
use msr_sim::Robot;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Output folder
    #[arg(long, default_value = "demo-out")]
    pub out: PathBuf,
    #[arg(long, default_value = "red")]
    pub robot: Robot,
    /// Face crop of the trained models: subpixel, or pixel (the published code)
    #[arg(long, default_value_t = crate::data::crop::CropMode::Subpixel)]
    pub crop: crate::data::crop::CropMode,
    /// Frames rendered (the paper's 1300)
    #[arg(long, default_value_t = 1300)]
    pub frames: usize,
    /// Training epochs (the paper's 50)
    #[arg(long, default_value_t = 50)]
    pub epochs: usize,
    /// Mirror-test trials in-process (and under QEMU when it is installed)
    #[arg(long, default_value_t = 40)]
    pub trials: usize,
    /// Of those, how many also run under QEMU (a few seconds each; capped at 75 s in all)
    #[arg(long, default_value_t = 5)]
    pub qemu_trials: usize,
    /// Folder of real frames in the published layout, for the real-frame check
    #[arg(long)]
    pub real: Option<PathBuf>,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// The servo bus of the episodes
    #[arg(long, value_enum, default_value_t = crate::episode::ServoBus::Dynamixel)]
    pub servo_bus: crate::episode::ServoBus,
    /// Only rewrite index.html from an earlier run's report.json, model.msrm and dataset in --out
    #[arg(long)]
    pub html_only: bool,
}

struct Progress {
    t0: Instant,
    step: Instant,
    timings: serde_json::Map<String, Value>,
}

impl Progress {
    fn start(&mut self, what: &str) {
        eprintln!("[{:>6.1} s] {what} ...", self.t0.elapsed().as_secs_f64());
        self.step = Instant::now();
    }
    fn done(&mut self, key: &str, detail: &str) {
        let s = self.step.elapsed().as_secs_f64();
        self.timings
            .insert(key.into(), json!((s * 100.0).round() / 100.0));
        eprintln!(
            "[{:>6.1} s]   {detail} ({s:.1} s)",
            self.t0.elapsed().as_secs_f64()
        );
    }
}

fn train_args(data: &Path, out: &Path, model: ModelKind, a: &Args) -> train::Args {
    train::Args {
        data: data.to_path_buf(),
        model,
        arch: ArchKind::Conv,
        conv_hidden: None,
        conv_channels: None,
        crop: a.crop,
        out: out.to_path_buf(),
        epochs: a.epochs,
        batch: 128,
        lr: 0.005,
        lr_step: 10,
        lr_decay: 0.5,
        seed: a.seed,
        normalisation: NormArg::Std,
        two_sided: false,
        sigma_floor: crate::train::calibrate::DEFAULT_SIGMA_FLOOR,
        threshold: crate::train::calibrate::DEFAULT_THRESHOLD,
        threshold_percentile: None,
        min_area: crate::train::calibrate::DEFAULT_MIN_AREA,
        pool: crate::train::calibrate::DEFAULT_POOL,
        device: DeviceArg::Cpu,
        quiet: true,
    }
}

pub fn run(a: Args) -> Result<()> {
    let out = a.out.clone();
    if a.html_only {
        let report: Value = serde_json::from_slice(
            &std::fs::read(out.join("report.json")).context("report.json of an earlier run")?,
        )?;
        let blob = std::fs::read(out.join("model.msrm")).context("model.msrm of an earlier run")?;
        crate::report::write_html(&out, &report, &blob, &out.join("dataset"))?;
        eprintln!("wrote {}", out.join("index.html").display());
        return Ok(());
    }
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
    train::run(train_args(&data, &models, ModelKind::Decoder, &a))?;
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
    train::run(train_args(&data, &models, ModelKind::Autoencoder, &a))?;
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
    let model_path = out.join("model.msrm");
    crate::fsio::write(&model_path, &blob)?;
    p.done(
        "quantize_s",
        &format!("{} ({} bytes)", model_path.display(), blob.len()),
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
            "{} rows, quantized agreement {:?}",
            eval.rows.len(),
            eval.quantized_agreement
        ),
    );
    eprint!("{}", crate::eval::markdown(&eval));

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
    p.done("episodes_inproc_s", &crate::cmd::mirror_test::readable(&inproc));
    let mut mirror = json!({ "inproc": inproc, "trials": trials });
    if msr_sim::qemu::qemu_available() {
        p.start(&format!(
            "   mirror-test episodes under QEMU (the first {} of the same trials, at most {} s)",
            a.qemu_trials,
            QEMU_BUDGET.as_secs()
        ));
        match qemu_episodes(&blob, &cfg, &trials, a.qemu_trials, a.seed) {
            Ok((s, matching, note)) => {
                p.done("episodes_qemu_s", &format!("{}; {note}", crate::cmd::mirror_test::readable(&s)));
                mirror["qemu"] = json!(s);
                mirror["qemu_matching_inproc"] = json!(matching);
                notes.push(format!("QEMU episodes: {note}."));
            }
            Err(e) => {
                p.done("episodes_qemu_s", &format!("QEMU episodes failed: {e:#}"));
                mirror["qemu"] = json!({ "error": format!("{e:#}") });
            }
        }
    } else {
        eprintln!("   qemu-system-arm is not installed: no QEMU episodes (apt-get install qemu-system-arm)");
        mirror["qemu"] = json!({ "error": "qemu-system-arm is not installed" });
    }

    // 7. Real frames.
    let real_dir = a
        .real
        .clone()
        .unwrap_or_else(|| PathBuf::from("../shared/data/nao-red-real"));
    let real = if real_dir.join(crate::data::MANIFEST_FILE).exists() {
        p.start(&format!(
            "7/8 the real-frame check with the imported published model ({})",
            real_dir.display()
        ));
        let r = real_check(&real_dir, &out)?;
        p.done("real_s", &format!("{r}"));
        r
    } else {
        eprintln!(
            "7/8 no real frames at {}: real-frame check skipped",
            real_dir.display()
        );
        json!({ "marked": null, "hits": null, "unmarked": null, "false_alarms": null, "skipped": format!("no {}", real_dir.display()) })
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
    p.timings
        .insert("total_s".into(), json!((total * 10.0).round() / 10.0));
    let report = json!({
        "robot": a.robot.name(),
        "eval": eval,
        "mirror_test": mirror,
        "real": real,
        "bench": bench,
        "timings": p.timings,
        "training": { "decoder": dec_info, "autoencoder": ae_info },
        "reach_fit_rms_rad": rms,
        "notes": notes,
    });
    crate::fsio::write(&out.join("report.json"), serde_json::to_vec_pretty(&report)?)?;
    crate::report::write_html(&out, &report, &blob, &data)?;
    eprintln!(
        "[{total:>6.1} s] wrote {0}/model.msrm, {0}/report.json, {0}/index.html",
        out.display()
    );
    Ok(())
}

/// The chosen novelty settings in a few words.
fn novelty_line(n: &crate::train::calibrate::NoveltyParams) -> String {
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
    let said = |c: &Option<train::policy::Choice>| match c {
        Some(c) => format!(
            "threshold {:.2}, merge {:?} ({}: of the candidates under which none of {} unmarked frames fires at the \
             threshold or at threshold / {}, the one finding most of {} marked ones)",
            c.threshold, c.merge, c.poses, c.normal_frames, c.safety, c.marked_frames
        ),
        None => "the paper's (no candidate kept the unmarked frames quiet)".into(),
    };
    format!(
        "Novelty settings by the calibrated policy (`train::policy`), not the paper's fixed 4.59 and plain blobs: at any \
         head pose {}; near the observe posture, where the robot looks for marks, {}{}.",
        said(&a.general),
        said(&a.observe),
        if a.novelty.region.is_none() { " (the same: no pose region)" } else { "" }
    )
}

/// Wall time the QEMU episodes may take: the emulated UART moves 20 to 40 KB/s, so a trial takes
/// a few seconds (the frames) and the model upload a few more.
const QEMU_BUDGET: std::time::Duration = std::time::Duration::from_secs(75);

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
    let upload_s = board.upload_s;
    let mut done = Vec::new();
    for i in 0..n {
        if t0.elapsed() > QEMU_BUDGET {
            break;
        }
        let camera = episode::Camera { renderer: &renderer, cropper: &cropper };
        done.push(board.trial(camera, cfg, i, episode::trial_seed(seed, i))?);
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
        "{} of {n} trials in {:.0} s (model upload {upload_s:.1} s over the emulated UART), {matching} the same as in-process",
        done.len(),
        t0.elapsed().as_secs_f64()
    );
    Ok((episode::summarise(Backend::Qemu, cfg.robot, cfg.servo_bus, &done), matching, note))
}

/// The published model on the real frames: marks found with the centroid in the box, and
/// detections on unmarked frames.
pub fn real_check(real_dir: &Path, out: &Path) -> Result<Value> {
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
    Ok(
        json!({ "marked": marked, "hits": hits, "unmarked": unmarked, "false_alarms": false_alarms }),
    )
}
