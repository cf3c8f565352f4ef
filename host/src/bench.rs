//! The firmware pipeline's benchmark: instruction counts, memory and code size.
//!
//! Two backends:
//! - `qemu` (default): the benchmark image (`msr-qemu-bench`) runs under QEMU's mps2-an386
//!   Cortex-M4 with `-icount shift=0`; stage figures are emulated instructions per frame
//!   (SysTick, 40-instruction resolution), the mean over 4 built-in frames (two with a mark),
//!   the decoder always run in full (uncached), then the threshold table of the pose's cell
//!   (`table`: made again only when the head changes cell), then the frame's own stages.
//!   `post_decoder_instructions_per_pixel` counts the table with the frame's stages (each bench
//!   frame is at a new pose); `held_pose_instructions_per_pixel` is a frame at the pose before,
//!   what most frames are while the robot observes (the mean of the 4), and
//!   `held_pose_worst_instructions_per_pixel` the costliest of them alone (a marked frame).
//!   `room`: what the online self-calibration adds once it has learnt (`msr_firmware::room`,
//!   the same learning sequence on the board and the host, whose offsets must agree): the
//!   offsets added to a new prediction (`apply_instructions`), and with them a new head pose in
//!   the same pose cell (`new_pose_*`), in another (`new_pose_cell_*`), a held frame learnt from,
//!   and the worst of these (`post_decoder_with_room_*`: the board never learns on a frame that
//!   made a new prediction). `apply` is a prediction with the offsets less one without: the
//!   default conv decoder adds them as its last layer stores the face.
//!   Stack peak: painted stack of the benchmark run.
//!   The image also reports a CRC-32 of each predicted face and the digest of the golden frames
//!   (`msr_firmware::golden`: every stage, masks and blobs included, at 16 head poses); the bench
//!   fails unless they equal the host build's (`"faces_match_host"`, `"golden_matches_host"`).
//!   Static RAM and code size: the board image (`msr-qemu`) as linked, read from its ELF
//!   (what runs on the robot): `code_bytes` = vector table + .text + .rodata (the target's "code
//!   without the model tables"), `flash_bytes` = code + .data's initial values + the model blob.
//! - `host`: the same library stages on this PC, timed with the OS clock; stage figures are
//!   nanoseconds per frame (median of the repetitions), `"unit": "ns"`. It says how fast the host
//!   tools run the pipeline and nothing about the board: instruction, RAM, flash and stack
//!   figures are `null` there. It adds a `crop` stage, which only the host runs: the face crop
//!   of a 320 x 240 camera frame (grey conversion, template match, cut) on one core, in the
//!   model's crop mode; `total_ns` counts the board's stages only.
//!
//! Models: `--model FILE` (repeatable) benchmarks those blobs. Without it, two blobs are made
//! here with the architectures of the default conv decoder and the published MLP decoder
//! (58 x 75), deterministic pseudo-random weights, i16 (or i8 with `--weights i8`, what
//! `msr quantize --weights auto` usually picks); the output says `"source": "synthetic"`.
//! Timing does not depend on the weight values, only on shapes and types.
//!
//! `"macs"` are the decoder's multiply-accumulates as its layers define them
//! (`Model::decoder_macs`): Dense inputs x outputs, ConvTranspose2d input elements x kernel^2 x
//! output channels (every product of the scatter), crops none. For the default conv decoder
//! that is 211 648, of which 209 064 reach the 58 x 75 face (the others land in the padding or
//! the column the crop drops).
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context, Result};
use msr_firmware::pipeline::Workspace;
use msr_firmware::reach;
use msr_firmware::saliency::Settings;
use msr_shared::blob::{
    CropMode, LayerKind, LayerSpec, Model, ModelSpec, Normalisation, Novelty, Reach, Sided, Weights,
};
use msr_shared::joints::{REACH_JOINTS, HOME_POSTURE};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::{json, Value};

use crate::models::{ArchKind, DecoderSpec};

/// Where the pipeline is benchmarked.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backend {
    /// The Cortex-M4 image under QEMU: emulated instructions.
    Qemu,
    /// This PC, in-process: nanoseconds.
    Host,
}

/// The weight type of the synthetic blobs.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum SynthWeights {
    /// 8-bit weights: the same values scaled to 7 bits.
    I8,
    /// 16-bit weights.
    I16,
}

/// Face size of the default models (the published crop).
pub const FACE: (u16, u16) = (58, 75);
/// The board's budgets the QEMU figures are held to: most decoder instructions per
/// multiply-accumulate.
pub const TARGET_INSTR_PER_MAC: f64 = 1.0;
/// Most instructions of the costliest frame: a new pose cell (the decoder, the offsets the
/// room learnt, the threshold table), a mark (the extent and the blob) and a frame floor that
/// changed (its table made again), or a frame the room learns from: 1.2 M, 6.7 ms at the
/// F429's 180 MHz, about one instruction a cycle.
pub const TARGET_WORST_FRAME: u64 = 1_200_000;
/// Most static RAM of the board image (.data, .bss, .uninit), bytes: the F429 has 256 KiB.
pub const TARGET_STATIC_RAM: u64 = 96 * 1024;
/// Most stack the benchmark run may reach, bytes.
pub const TARGET_STACK: u64 = 8 * 1024;
/// Most code of the board image (vector table, .text, .rodata), bytes: the F429 has 2 MiB of
/// flash, which also holds the model blob and the store.
pub const TARGET_CODE: u64 = 192 * 1024;

/// One model to benchmark.
pub struct BenchModel {
    /// `"conv"`, `"published-mlp"`, or the file stem for another architecture.
    pub name: String,
    /// `"synthetic"` or the file it came from.
    pub source: String,
    /// The model blob's bytes.
    pub blob: Vec<u8>,
}

/// Reads a blob and names it by its architecture.
pub fn from_file(path: &Path) -> Result<BenchModel> {
    let blob = crate::fsio::read_blob(path)?;
    let model = Model::parse(&blob).map_err(|e| anyhow::anyhow!("model {}: {e}", path.display()))?;
    let name = arch_name(&model).unwrap_or_else(|| {
        path.file_stem().map_or("model".into(), |s| s.to_string_lossy().into_owned())
    });
    drop(model);
    Ok(BenchModel { name, source: path.display().to_string(), blob })
}

/// `"conv"` for a decoder with convolutions, `"published-mlp"` for 2-12-64-128-(h*w).
pub fn arch_name(model: &Model) -> Option<String> {
    let conv = model
        .layers
        .iter()
        .any(|l| matches!(l.kind, LayerKind::ConvTranspose2d | LayerKind::UpConv));
    let widths: Vec<usize> = model.layers.iter().map(|l| l.output.len()).collect();
    if conv {
        Some("conv".into())
    } else if widths == [12, 64, 128, model.face_pixels()] {
        Some("published-mlp".into())
    } else {
        None
    }
}

/// A blob with the architecture of `kind` at 58 x 75 and deterministic weights.
pub fn synthetic(kind: ArchKind) -> Result<BenchModel> {
    synthetic_with(kind, false)
}

/// [`synthetic`] with i8 weights when `i8w` (the same values scaled to 7 bits).
pub fn synthetic_with(kind: ArchKind, i8w: bool) -> Result<BenchModel> {
    synthetic_model(kind, i8w, false)
}

/// [`synthetic_with`] with what `msr train` gives by default after the decoder: the pooled
/// error (radius 2), the one-sided test, statistics in 3 x 3 head-pose cells (each cell's mu
/// and sigma a little different). The source says "pooled".
pub fn synthetic_pooled(kind: ArchKind, i8w: bool) -> Result<BenchModel> {
    synthetic_model(kind, i8w, true)
}

fn synthetic_model(kind: ArchKind, i8w: bool, pooled: bool) -> Result<BenchModel> {
    let (h, w) = FACE;
    let spec = DecoderSpec::new(kind, h as usize, w as usize);
    let shapes = spec.layer_shapes()?;
    let mut rng = ChaCha8Rng::seed_from_u64(0x6d73_725f_6265_6e63);
    // Angles of a few tenths of a radian in Q12; activations in Q14 (tanh and sigmoid <= 1).
    let mut in_shift = 12i8;
    let act_shift = 14i8;
    let mut layers = Vec::new();
    for (kind, act, input, output) in shapes {
        let (n_w, n_b, fan_in) = match kind {
            LayerKind::Dense => (input.len() * output.len(), output.len(), input.len()),
            LayerKind::ConvTranspose2d => {
                let k = spec.conv.as_ref().map_or(1, |c| c.kernel);
                (input.c as usize * output.c as usize * k * k, output.c as usize, output.c as usize * k * k)
            }
            _ => (0, 0, 1),
        };
        let (kernel, stride, padding, crop) = match (&spec.conv, kind) {
            (Some(c), LayerKind::ConvTranspose2d) => (c.kernel as u8, c.stride as u8, c.padding as u8, [0, 0]),
            (Some(c), LayerKind::Crop) => (0, 0, 0, [c.crop[0] as u16, c.crop[1] as u16]),
            _ => (0, 0, 0, [0, 0]),
        };
        let bound = 1.0 / (fan_in as f64).sqrt();
        // As many weight bits as fit, keeping |acc| < 2^30 for inputs up to 1.0.
        let taps = (fan_in as f64).log2().ceil() as i32;
        let w_max = if i8w { 127.0 } else { 32767.0 };
        let w_shift = ((w_max / bound).log2().floor() as i32).min(30 - in_shift as i32 - taps).clamp(0, 31) as i8;
        let scale = (w_shift as f64).exp2();
        let values: Vec<f64> = (0..n_w).map(|_| (rng.gen_range(-bound..bound) * scale).round()).collect();
        let weights = if i8w {
            Weights::I8(values.iter().map(|&v| v as i8).collect())
        } else {
            Weights::I16(values.iter().map(|&v| v as i16).collect())
        };
        let acc_scale = ((w_shift + in_shift) as f64).exp2();
        let bias: Vec<i32> =
            (0..n_b).map(|_| (rng.gen_range(-bound..bound) * acc_scale).round() as i32).collect();
        let out_shift = if kind == LayerKind::Crop { in_shift } else { act_shift };
        layers.push(LayerSpec {
            kind,
            activation: act,
            input,
            output,
            kernel,
            stride,
            padding,
            crop_top: crop[0],
            crop_left: crop[1],
            w_shift: if kind == LayerKind::Crop { 0 } else { w_shift },
            in_shift,
            out_shift,
            weights,
            bias,
        });
        in_shift = out_shift;
    }
    let n = h as usize * w as usize;
    // Error statistics: mean 3 grey levels, sigma 1.5..3.5, in Q8.8.
    let mu = vec![3 * 256; n];
    let sigma = (0..n).map(|i| (384 + (i * 37 % 512)) as u16).collect();
    let mut r = |n: usize| (0..n).map(|_| rng.gen_range(-2.0f32..2.0)).collect::<Vec<f32>>();
    let (w1, b1, w2, b2) = (r(20), r(10), r(50), r(5));
    let mut out_min = [0f32; 5];
    let mut out_max = [0f32; 5];
    for (i, (j, home)) in REACH_JOINTS.iter().zip(HOME_POSTURE).enumerate() {
        let l = j.limits().context("reach joints have limits")?;
        out_min[i] = (home - 0.5).max(l.min);
        out_max[i] = (home + 0.5).min(l.max);
    }
    let reach = Reach::from_parts(&w1, &b1, &w2, &b2, [0.0, 0.0], [320.0, 240.0], out_min, out_max)
        .map_err(|e| anyhow::anyhow!("synthetic reach net: {e}"))?;
    let spec = ModelSpec {
        face_h: h,
        face_w: w,
        novelty: Novelty {
            threshold: 4.59,
            normalisation: Normalisation::StdDev,
            sided: Sided::Two,
            min_area: 30,
            sigma_floor: 1.0,
            merge: msr_shared::blob::Merge::OFF,
            pool: 0,
            spread_ref: None,
        },
        layers,
        mu,
        sigma,
        reach,
        region: None,
        template: None,
        crop: CropMode::Pixel,
        pose: None,
    };
    let spec = if pooled {
        let cells = (0..9u16)
            .map(|c| {
                let mu = spec.mu.iter().map(|&m| m + c * 40).collect();
                let sigma = spec.sigma.iter().map(|&s| s + (c % 4) * 60).collect();
                (mu, sigma)
            })
            .collect();
        let grid = msr_shared::blob::PoseGrid { bins: [3, 3], lo: [-0.0873; 2], hi: [0.0873; 2] };
        ModelSpec {
            novelty: Novelty { sided: Sided::One, pool: 2, ..spec.novelty },
            pose: Some((grid, cells)),
            ..spec
        }
    } else {
        spec
    };
    let blob = spec.to_bytes().map_err(|e| anyhow::anyhow!("synthetic {kind:?} blob: {e}"))?;
    let name = match kind {
        ArchKind::Conv => "conv",
        ArchKind::Mlp => "published-mlp",
    };
    let source = match (i8w, pooled) {
        (false, false) => "synthetic",
        (true, false) => "synthetic, i8 weights",
        (false, true) => "synthetic, pooled",
        (true, true) => "synthetic, i8 weights, pooled",
    };
    Ok(BenchModel { name: name.into(), source: source.into(), blob })
}

/// Head poses of the benchmark frames; the QEMU image uses the same ones.
pub const POSES: [[f32; 2]; 4] = [[0.0, 0.0], [0.05, -0.03], [-0.07, 0.02], [0.02, 0.06]];
const MARK: usize = 15;
const MARK_GREY: u8 = 226;

/// The benchmark frames, made as the QEMU bench image makes them: prediction, +-2 noise,
/// a 15 x 15 mark of grey 226 on even frames.
pub fn frames(model: &Model, ws: &mut Workspace) -> Result<Vec<Vec<u8>>> {
    let (h, w) = (model.face_h as usize, model.face_w as usize);
    let mut rng = 0x1234_5678u32;
    let mut noise = || {
        rng = rng.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        ((rng >> 24) % 5) as i32 - 2
    };
    let mut out = Vec::new();
    for (k, head) in POSES.iter().enumerate() {
        let face = ws.decode(model, *head).map_err(|e| anyhow::anyhow!("decoder: {e}"))?;
        let mut frame: Vec<u8> =
            face.iter().map(|&q| (((q as i32 + 128) >> 8) + noise()).clamp(0, 255) as u8).collect();
        if k % 2 == 0 && h >= MARK && w >= MARK {
            let (y0, x0) = ((h - MARK) * (k + 1) / 5, (w - MARK) * (4 - k) / 5);
            for y in y0..y0 + MARK {
                frame[y * w + x0..y * w + x0 + MARK].fill(MARK_GREY);
            }
        }
        out.push(frame);
    }
    Ok(out)
}

fn median(mut v: Vec<Duration>) -> f64 {
    v.sort();
    v[v.len() / 2].as_nanos() as f64
}

/// The library's stages on this PC.
pub fn bench_host(m: &BenchModel, reps: usize) -> Result<Value> {
    let model = Model::parse(&m.blob).map_err(|e| anyhow::anyhow!("{}: {e}", m.source))?;
    let mut ws = Box::new(Workspace::new());
    let settings = Settings::of(&model);
    let frames = frames(&model, &mut ws)?;
    let (mut dec, mut sal, mut blo, mut rea) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (frame, head) in frames.iter().zip(POSES) {
        for _ in 0..reps {
            let t0 = Instant::now();
            ws.decoder.predict_uncached(&model, head).map_err(|e| anyhow::anyhow!("decoder: {e}"))?;
            let t1 = Instant::now();
            ws.saliency(&model, &settings, frame).map_err(|e| anyhow::anyhow!("saliency: {e}"))?;
            let t2 = Instant::now();
            let (blob, _) = ws.blobs(&model, &settings);
            let t3 = Instant::now();
            let c = blob.map_or([model.face_w as f32 / 2.0, model.face_h as f32 / 2.0], |b| b.centroid());
            std::hint::black_box(reach::targets(&model.reach, c));
            let t4 = Instant::now();
            dec.push(t1 - t0);
            sal.push(t2 - t1);
            blo.push(t3 - t2);
            rea.push(t4 - t3);
        }
    }
    let stages = [median(dec), median(sal), median(blo), median(rea)];
    let macs = model.decoder_macs();
    // The host's face crop of a 320 x 240 camera frame (grey conversion, template match, cut),
    // on one core, in the model's crop mode: frames of the red robot at a few head poses.
    let renderer = msr_sim::render::Renderer::new(msr_sim::Robot::Red);
    let cropper = crate::data::crop::Cropper::new(renderer.template(), crate::detect::crop_mode_of(&model));
    let mut crop = Vec::new();
    for head in POSES {
        let pose = msr_sim::body::BodyPose::head(head[0] as f64, head[1] as f64);
        let rgb = image::DynamicImage::ImageRgb8(renderer.render(&pose, None, &msr_sim::render::Variation::CLEAN).rgb);
        for _ in 0..reps {
            let t0 = Instant::now();
            std::hint::black_box(cropper.crop(&crate::data::crop::to_grey(&rgb))?);
            crop.push(t0.elapsed());
        }
    }
    let crop = median(crop);
    Ok(json!({
        "backend": "host",
        "unit": "ns",
        "model": m.name,
        "source": m.source,
        "face": [model.face_h, model.face_w],
        "macs": macs,
        "stages": {"decoder": stages[0], "saliency": stages[1], "blobs": stages[2], "reach": stages[3], "crop": crop},
        "total_instructions": null,
        "total_ns": stages.iter().sum::<f64>(),
        "instructions_per_mac": null,
        "ns_per_mac": stages[0] / macs.max(1) as f64,
        "static_ram_bytes": null,
        "flash_bytes": null,
        "stack_peak_bytes": null,
        "workspace_bytes": std::mem::size_of::<Workspace>(),
    }))
}

/// The benchmark image under QEMU, plus the board image's sizes.
pub fn bench_qemu(m: &BenchModel) -> Result<Value> {
    use msr_sim::qemu;
    ensure!(
        qemu::qemu_available(),
        "{} is not installed: install qemu-system-arm (Debian: apt-get install qemu-system-arm) \
         or bench on the host",
        qemu::qemu_binary()
    );
    let model = Model::parse(&m.blob).map_err(|e| anyhow::anyhow!("{}: {e}", m.source))?;
    let bench_image = qemu::find_image(qemu::BENCH_IMAGE)?;
    let board_image = qemu::find_image(qemu::BOARD_IMAGE)?;
    // The model goes into the board's PSRAM with QEMU's loader, not over the emulated UART
    // (one byte per turn of QEMU's event loop: the demo's model took 16 s there).
    let preload = qemu::preload_bytes(&m.blob);
    let opts = qemu::Options { preload: Some(&preload), ..qemu::Options::default() };
    let exit = qemu::run_image(&bench_image, &opts, Duration::from_secs(300), |_, _| Ok(()))?;
    if let Some(l) = exit.output.lines().find(|l| l.starts_with("MSR-BENCH-ERROR")) {
        bail!("the benchmark image refused: {l}");
    }
    exit.success()?;
    let line = exit
        .output
        .lines()
        .find_map(|l| l.strip_prefix("MSR-BENCH "))
        .with_context(|| format!("no MSR-BENCH line in the image's output:\n{}", exit.output))?;
    let r: Value = serde_json::from_str(line).with_context(|| format!("parsing {line}"))?;
    // The board's faces must be the host build's, bit for bit.
    let host_crcs = host_face_crcs(&model)?;
    let board_crcs: Vec<u64> = r["face_crc32"]
        .as_array()
        .map(|a| a.iter().filter_map(Value::as_u64).collect())
        .unwrap_or_default();
    ensure!(
        board_crcs == host_crcs,
        "the board's predicted faces differ from the host build's (CRC-32 {board_crcs:?} vs {host_crcs:?})"
    );
    let host_golden = host_golden(&model)?;
    ensure!(
        r["golden_digest"].as_u64() == Some(host_golden.digest as u64),
        "the board's golden frames differ from the host build's (digest {} vs {}): a pipeline stage \
         after the decoder computes differently on the board",
        r["golden_digest"],
        host_golden.digest
    );
    let host_room = host_room(&model)?;
    ensure!(
        r["room"]["digest"].as_u64() == Some(host_room.digest as u64),
        "the board's online self-calibration learnt other offsets than the host build's (digest {} vs {})",
        r["room"]["digest"],
        host_room.digest
    );
    let room = |k: &str| r["room"][k].as_u64().unwrap_or(0);
    let stage = |k: &str| r["stages"][k].as_u64().unwrap_or(0);
    // The colour stage counts with the saliency's (it follows it on every frame); an image
    // that does not report it is older than a model with chroma.
    let chroma = match r["stages"]["chroma"].as_u64() {
        Some(c) => c,
        None if model.chroma.is_none() => 0,
        None => bail!("the benchmark image reports no chroma stage: it is older than this msr (cargo xtask images)"),
    };
    let stages = [stage("decoder"), stage("saliency") + chroma, stage("blobs"), stage("reach")];
    let table = stage("table");
    // Required: read as 0, an image that does not report it would leave the floor's table out
    // of the costliest frame.
    let table_widened = r["stages"]["table_widened"]
        .as_u64()
        .context("the benchmark image reports no table_widened: it is older than this msr (cargo xtask images)")?;
    let total: u64 = stages.iter().sum::<u64>() + table;
    let macs = model.decoder_macs();
    let pixels = model.face_pixels() as f64;
    let board = elf_sizes(&board_image)?;
    let code = board.code;
    let flash = code + board.data_init + m.blob.len() as u64;
    let per_mac = stages[0] as f64 / macs.max(1) as f64;
    // After the decoder: the threshold table of a new pose cell included (each bench frame is at
    // another pose). A frame at the pose before (the robot observing with its head still) does
    // without it: `held_pose`.
    let held = (stages[1] + stages[2] + stages[3]) as f64 / pixels;
    // The mean is over the bench's frames, two of them marked; the costliest alone (a marked
    // frame: the extent and the blob) is `held_pose_worst`.
    // Required: read as 0, an image that does not report it would call the target met.
    let held_worst = r["held_max"]
        .as_u64()
        .context("the benchmark image reports no held_max: it is older than this msr (cargo xtask images)")?
        as f64
        / pixels;
    let post = held + table as f64 / pixels;
    // A new head pose once the room has learnt: the decoder runs and the offsets are added to
    // its prediction (`apply`), inside the same pose cell (no table; the bench frames' mean and
    // costliest) or in another (the table made again too).
    let apply = room("apply") as f64 / pixels;
    let (new_pose, new_pose_worst, new_cell) = (held + apply, held_worst + apply, post + apply);
    // A frame learnt from: the head still, no blob, and its prediction from the cache (the
    // board never learns on a frame that made a new one), so the worst of those is the
    // costliest held frame without a blob plus the costlier of a frame learnt from (`learn`:
    // its samples) and the frame that settles a batch of 8 (`update`: every offset moved; the
    // board never does both on one frame, nor either on a new prediction).
    let held_clear = r["held_clear_max"]
        .as_u64()
        .context("the benchmark image reports no held_clear_max: it is older than this msr (cargo xtask images)")?
        as f64
        / pixels;
    let held_learning = held_clear + room("learn").max(room("update")) as f64 / pixels;
    // The worst frame once the room has learnt: a new pose cell with the offsets, or a held
    // frame learnt from.
    let with_room = new_cell.max(held_learning);
    // The costliest frame: a new pose cell (the decoder, the offsets added, the table made with
    // each sigma widened by a frame floor, the costlier of the two tables) with the costliest
    // held frame's stages after it (a mark), or the costliest frame learnt from (no decoder).
    // A model whose bench frames have a floor pays a table in those stages too: then this
    // counts one table twice, an upper bound.
    let worst_table = table.max(table_widened) as f64;
    let worst_frame = (stages[0] as f64 + new_pose_worst * pixels + worst_table).max(held_learning * pixels).round() as u64;
    let stack = r["stack_peak_bytes"].as_u64().unwrap_or(0);
    Ok(json!({
        "backend": "qemu",
        "unit": "instructions",
        "model": m.name,
        "source": m.source,
        "face": [model.face_h, model.face_w],
        "macs": macs,
        "stages": {"decoder": stages[0], "table": table, "table_widened": table_widened, "saliency": stages[1] - chroma, "chroma": chroma, "blobs": stages[2], "reach": stages[3]},
        "total_instructions": total,
        "worst_frame_instructions": worst_frame,
        "instructions_per_mac": round3(per_mac),
        "post_decoder_instructions_per_pixel": round3(post),
        "held_pose_instructions_per_pixel": round3(held),
        "held_pose_worst_instructions_per_pixel": round3(held_worst),
        "room": {
            "learn_instructions": room("learn"),
            "update_instructions": room("update"),
            "apply_instructions": room("apply"),
            "matches_host": true,
            "post_decoder_with_room_instructions_per_pixel": round3(with_room),
            "held_pose_learning_instructions_per_pixel": round3(held_learning),
            "new_pose_instructions_per_pixel": round3(new_pose),
            "new_pose_worst_instructions_per_pixel": round3(new_pose_worst),
            "new_pose_cell_instructions_per_pixel": round3(new_cell),
        },
        "static_ram_bytes": board.ram,
        "flash_bytes": flash,
        "code_bytes": code,
        "data_init_bytes": board.data_init,
        "model_bytes": m.blob.len(),
        "stack_peak_bytes": stack,
        "faces_match_host": true,
        "golden_matches_host": true,
        "golden_detections": host_golden.detections,
        "frames": r["frames"],
        "marks_found": r["marks_found"],
        "bench_image": {"static_ram_bytes": r["static_ram_bytes"], "code_bytes": r["code_bytes"]},
        "targets": {
            "instructions_per_mac": {"max": TARGET_INSTR_PER_MAC, "met": per_mac <= TARGET_INSTR_PER_MAC},
            "worst_frame_instructions": {"max": TARGET_WORST_FRAME, "met": worst_frame <= TARGET_WORST_FRAME},
            "static_ram_bytes": {"max": TARGET_STATIC_RAM, "met": board.ram <= TARGET_STATIC_RAM},
            "stack_peak_bytes": {"max": TARGET_STACK, "met": stack <= TARGET_STACK},
            "code_bytes": {"max": TARGET_CODE, "met": code <= TARGET_CODE},
        },
    }))
}

/// The golden frames through the host build (`msr_firmware::golden::run`).
pub fn host_golden(model: &Model) -> Result<msr_firmware::golden::GoldenReport> {
    let mut ws = Box::new(Workspace::new());
    let mut crop = vec![0u8; msr_firmware::golden::scratch_len(model)];
    msr_firmware::golden::run(&mut ws, model, &mut crop).map_err(|e| anyhow::anyhow!("host golden frames: {e}"))
}

/// The room's fixed sequence ([`msr_firmware::golden::room`]) on the host build.
pub fn host_room(model: &Model) -> Result<msr_firmware::golden::RoomReport> {
    let mut ws = Box::new(Workspace::new());
    let mut crop = vec![0u8; model.face_pixels()];
    msr_firmware::golden::room(&mut ws, model, &mut crop, || 0).map_err(|e| anyhow::anyhow!("host room: {e}"))
}

/// CRC-32 of the host build's predicted face (u16 little-endian) for each of [`POSES`], as the
/// benchmark image computes it.
pub fn host_face_crcs(model: &Model) -> Result<Vec<u64>> {
    let mut dec = Box::new(msr_firmware::decoder::Decoder::new());
    POSES
        .iter()
        .map(|&head| {
            let face = dec
                .predict_uncached(model, head)
                .map_err(|e| anyhow::anyhow!("host decoder: {e}"))?;
            let mut d = msr_shared::blob::CRC32.digest();
            face.iter().for_each(|v| d.update(&v.to_le_bytes()));
            Ok(d.finalize() as u64)
        })
        .collect()
}

fn round3(x: f64) -> f64 {
    (x * 1000.0).round() / 1000.0
}

/// Allocated sections of a linked image.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ElfSizes {
    /// Vector table, code and read-only data.
    pub code: u64,
    /// Initial values of .data, stored in flash and copied to RAM at start-up.
    pub data_init: u64,
    /// .data, .bss, .uninit: RAM that is not stack.
    pub ram: u64,
}

/// Reads the section table of a 32-bit little-endian ELF file. Sections below `0x2000_0000` are
/// flash, those from it on RAM; `NOBITS` sections in flash (the model upload area) are not
/// programmed and not counted.
pub fn elf_sizes(path: &Path) -> Result<ElfSizes> {
    let b = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    ensure!(b.len() >= 52 && b[..4] == *b"\x7fELF" && b[4] == 1 && b[5] == 1, "{} is not a 32-bit little-endian ELF file", path.display());
    let u16_at = |o: usize| -> Result<u64> {
        Ok(u16::from_le_bytes(b.get(o..o + 2).context("truncated ELF")?.try_into()?) as u64)
    };
    let u32_at = |o: usize| -> Result<u64> {
        Ok(u32::from_le_bytes(b.get(o..o + 4).context("truncated ELF")?.try_into()?) as u64)
    };
    let (shoff, shentsize, shnum) = (u32_at(0x20)?, u16_at(0x2E)?, u16_at(0x30)?);
    const SHF_ALLOC: u64 = 2;
    const SHT_NOBITS: u64 = 8;
    const RAM: u64 = 0x2000_0000;
    let mut s = ElfSizes::default();
    for i in 0..shnum {
        let h = (shoff + i * shentsize) as usize;
        let (kind, flags, addr, size) = (u32_at(h + 4)?, u32_at(h + 8)?, u32_at(h + 12)?, u32_at(h + 20)?);
        if flags & SHF_ALLOC == 0 || size == 0 {
            continue;
        }
        if addr >= RAM {
            s.ram += size;
            if kind != SHT_NOBITS {
                s.data_init += size;
            }
        } else if kind != SHT_NOBITS {
            s.code += size;
        }
    }
    Ok(s)
}

/// The results of one model as a table on stdout.
pub fn print_table(v: &Value) {
    let unit = v["unit"].as_str().unwrap_or("");
    println!("{} ({}, {}), {} MACs, figures in {} per frame:", v["model"].as_str().unwrap_or("?"), v["backend"].as_str().unwrap_or("?"), v["source"].as_str().unwrap_or("?"), v["macs"], unit);
    for k in ["decoder", "table", "saliency", "blobs", "reach", "crop"] {
        if v["stages"][k].is_null() {
            continue;
        }
        println!("  {k:<10} {}", v["stages"][k]);
    }
    for k in ["instructions_per_mac", "post_decoder_instructions_per_pixel", "held_pose_instructions_per_pixel", "held_pose_worst_instructions_per_pixel", "ns_per_mac", "static_ram_bytes", "code_bytes", "flash_bytes", "stack_peak_bytes"] {
        if !v[k].is_null() {
            let target = &v["targets"][k];
            let note = if target.is_null() { String::new() } else { format!("  (target <= {}: {})", target["max"], if target["met"].as_bool() == Some(true) { "met" } else { "NOT met" }) };
            println!("  {k:<38} {}{note}", v[k]);
        }
    }
    let room = &v["room"];
    if !room["apply_instructions"].is_null() {
        println!("  the room's offsets, once learnt (instructions a pixel after the decoder):");
        for (k, what) in [
            ("new_pose_instructions_per_pixel", "new head pose, same pose cell (mean)"),
            ("new_pose_worst_instructions_per_pixel", "new head pose, same pose cell (costliest)"),
            ("new_pose_cell_instructions_per_pixel", "new pose cell"),
            ("held_pose_learning_instructions_per_pixel", "held pose, a frame learnt from"),
            ("post_decoder_with_room_instructions_per_pixel", "the worst of these"),
        ] {
            println!("    {what:<42} {}", room[k]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The benchmark image's faces equal the host build's for both weight types (the assembly
    /// kernels differ: SMLAD on i16 pairs, SXTB16 + SMLAD on i8), so do the golden frames
    /// (every stage after the decoder) for the per-pixel two-sided test and the pooled
    /// one-sided one with pose cells (its assembly row and table routines), and it reports
    /// every stage.
    #[test]
    fn qemu_bench_faces_and_golden_frames_match_the_host() {
        use msr_sim::qemu;
        if !qemu::qemu_available()
            || qemu::find_image(qemu::BENCH_IMAGE).is_err()
            || qemu::find_image(qemu::BOARD_IMAGE).is_err()
        {
            eprintln!("skipped: QEMU or the firmware images are missing (cargo xtask images)");
            return;
        }
        for (i8w, pooled) in [(false, false), (true, false), (false, true)] {
            for kind in [ArchKind::Conv, ArchKind::Mlp] {
                let m = synthetic_model(kind, i8w, pooled).unwrap();
                let v = bench_qemu(&m).unwrap();
                assert_eq!(v["faces_match_host"], true);
                assert_eq!(v["golden_matches_host"], true);
                for s in ["decoder", "saliency", "blobs", "reach"] {
                    assert!(v["stages"][s].as_u64().unwrap() > 0, "{kind:?} i8 {i8w}: {s}");
                }
                assert_eq!(v["marks_found"], 2, "{kind:?} i8 {i8w} pooled {pooled}");
                let (mean, worst) = (v["held_pose_instructions_per_pixel"].as_f64().unwrap(), v["held_pose_worst_instructions_per_pixel"].as_f64().unwrap());
                assert!(worst >= mean && worst > 0.0, "{kind:?} i8 {i8w} pooled {pooled}: worst {worst}, mean {mean}");
                // The offsets the room learnt cost something, on top of each held figure.
                let r = |k: &str| v["room"][k].as_f64().unwrap();
                assert!(r("apply_instructions") > 0.0, "{kind:?} i8 {i8w} pooled {pooled}: no offsets added");
                assert!(r("new_pose_instructions_per_pixel") > mean, "{kind:?} i8 {i8w} pooled {pooled}");
                assert!(r("new_pose_worst_instructions_per_pixel") > worst, "{kind:?} i8 {i8w} pooled {pooled}");
                let cell = v["post_decoder_instructions_per_pixel"].as_f64().unwrap();
                assert!(r("new_pose_cell_instructions_per_pixel") > cell, "{kind:?} i8 {i8w} pooled {pooled}");
            }
        }
    }
}
