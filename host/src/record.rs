//! Recording a training set on the robot itself, the paper's head babbling: the
//! host asks the board for a head pose drawn uniformly within the range, waits until the board
//! says the servos settled there, grabs the next camera frame, and stores it with the head angles
//! the servos reported (not the ones asked for), in the dataset layout that training reads
//! (`msr_sim::layout`, robot "recorded", a seeded train/test split).
//!
//! On disk while it runs: `frames/NNNNNN.png` and `recording.csv` (one line per pose tried:
//! `frame,FILE,yaw,pitch` or `skip,REASON,yaw,pitch`), each frame's line appended after its PNG
//! is whole. `dataset.json` and `head_angles.csv` are written last: a folder without them is an
//! unfinished recording, which a resumed recording continues and training refuses.
use crate::camera::{self, Frames, SourceConfig, SourceOptions};
use crate::session::Session;
use crate::data::crop::{self, CropMode, Cropper};
use crate::fsio;
use anyhow::{bail, Context, Result};
use image::GrayImage;
use msr_shared::joints::Joint;
use msr_shared::msg::{BoardToHost, ErrorCode, HostToBoard};
use msr_sim::layout::{self, DatasetIndex, FrameRecord, Split};
use rand::{Rng, SeedableRng};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// The log of a recording in progress.
pub const LOG_FILE: &str = "recording.csv";
/// A crop whose correlation with the template is below this is not a face: the frame is skipped.
pub const MIN_FACE_CORRELATION: f64 = 0.5;
/// Poses tried per frame kept, at most, before the recording gives up.
pub const MAX_TRIES_PER_FRAME: usize = 4;

/// What to record.
#[derive(Clone, Debug, PartialEq)]
pub struct RecordConfig {
    /// The board's serial port.
    pub port: String,
    /// The serial line's rate, bits per second.
    pub baud: u32,
    /// The camera the frames come from.
    pub source: SourceConfig,
    /// Frames to keep.
    pub count: usize,
    /// The dataset folder written.
    pub out: PathBuf,
    /// Head angles are drawn uniformly in +-range, degrees.
    pub range_deg: f64,
    /// Seed of the head poses drawn and of the train/test split.
    pub seed: u64,
    /// Continue an unfinished recording in `out`.
    pub resume: bool,
    /// Start again over a finished (or unfinished) recording in `out`.
    pub force: bool,
    /// The face template (grey PNG); default `out/template.png`, or the sim's for a sim camera.
    pub template: Option<PathBuf>,
    /// Share of the frames in the test split (0 to 1).
    pub test_fraction: f64,
    /// Longest wait for the board's answer to a head pose.
    pub head_timeout: Duration,
    /// Longest wait for a camera frame.
    pub frame_timeout: Duration,
    /// Prints a banner and shows a progress bar on stderr.
    pub progress: bool,
    /// Also write the recording as MCAP (`--mcap`).
    pub mcap: Option<PathBuf>,
    /// Publish the recording live as it is made (`--live`).
    pub live: Option<std::sync::Arc<crate::live::Live>>,
}

impl RecordConfig {
    /// A recording with the defaults: 921 600 baud, head within +-5 degrees, seed 0, a fifth of
    /// the frames for testing, 5 s timeouts, no MCAP or live output.
    pub fn new(port: &str, source: SourceConfig, count: usize, out: &Path) -> RecordConfig {
        RecordConfig {
            port: port.into(),
            baud: 921_600,
            source,
            count,
            out: out.into(),
            range_deg: 5.0,
            seed: 0,
            resume: false,
            force: false,
            template: None,
            test_fraction: 0.2,
            head_timeout: Duration::from_secs(5),
            frame_timeout: Duration::from_secs(5),
            progress: false,
            mcap: None,
            live: None,
        }
    }
}

/// What a recording did.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Recorded {
    /// Frames taken by this run.
    pub frames: usize,
    /// Frames taken by an earlier, interrupted run.
    pub resumed: usize,
    /// Frames where the template was not found.
    pub skipped_no_face: usize,
    /// Poses the servos did not settle at in time.
    pub skipped_not_settled: usize,
    /// Largest difference between a pose asked for and the one the servos reported, degrees.
    pub max_pose_error_deg: f64,
}

/// One line of the log.
#[derive(Clone, Debug, PartialEq)]
enum Entry {
    Frame { file: String, head: [f64; 2] },
    Skip,
}

fn read_log(path: &Path) -> Result<Vec<Entry>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let f: Vec<&str> = line.split(',').collect();
        let bad = || anyhow::anyhow!("{} line {}: not a recording log line: {line:?}", path.display(), i + 1);
        match f.as_slice() {
            ["frame", file, y, p] => {
                let head = [y.parse().map_err(|_| bad())?, p.parse().map_err(|_| bad())?];
                out.push(Entry::Frame { file: file.to_string(), head });
            }
            ["skip", ..] => out.push(Entry::Skip),
            // A line cut by an interruption is the last one: the pose is tried again.
            _ if i + 1 == text.lines().count() && !text.ends_with('\n') => {}
            _ => return Err(bad()),
        }
    }
    Ok(out)
}

/// Pearson correlation of two equal-size grey images (0 when either is flat).
pub fn correlation(a: &[u8], b: &[u8]) -> f64 {
    let n = a.len().min(b.len()) as f64;
    if n == 0.0 {
        return 0.0;
    }
    let (ma, mb) = (
        a.iter().map(|&v| v as f64).sum::<f64>() / n,
        b.iter().map(|&v| v as f64).sum::<f64>() / n,
    );
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (&x, &y) in a.iter().zip(b) {
        let (x, y) = (x as f64 - ma, y as f64 - mb);
        sab += x * y;
        saa += x * x;
        sbb += y * y;
    }
    if saa == 0.0 || sbb == 0.0 {
        0.0
    } else {
        sab / (saa * sbb).sqrt()
    }
}

/// The template to record with: given, already in `out`, or the sim robot's.
fn template(cfg: &RecordConfig) -> Result<GrayImage> {
    let in_out = cfg.out.join(layout::TEMPLATE_FILE);
    if let Some(p) = &cfg.template {
        return crop::load_grey(p);
    }
    if in_out.is_file() {
        return crop::load_grey(&in_out);
    }
    if let SourceConfig::Sim { robot, .. } = cfg.source {
        return Ok(msr_sim::render::Renderer::new(robot).template());
    }
    Err(OutError::NoTemplate(in_out).into())
}

/// Why the output folder cannot take this recording as configured. The words name the
/// configuration's fields (`force`, `resume`, `count`); the command line says the same with its
/// flags.
#[derive(Debug, Clone, PartialEq)]
pub enum OutError {
    /// `out` is a file.
    NotAFolder(PathBuf),
    /// `out` holds a finished recording or dataset, and `force` is off.
    Finished(PathBuf),
    /// `out` holds an unfinished recording, and neither `resume` nor `force` is on.
    Unfinished(PathBuf),
    /// `out` holds files, but no recording.
    NotEmpty(PathBuf),
    /// The unfinished recording's log disagrees with its folder (`what` says how): only recording
    /// again over it (`force`) helps.
    BadLog {
        /// The log file.
        log: PathBuf,
        /// How the log and the folder disagree.
        what: String,
    },
    /// No face template: none configured, none in `out` (the path it would have) and no sim camera.
    NoTemplate(PathBuf),
    /// The unfinished recording already holds more frames than `count`.
    TooMany {
        /// The log file.
        log: PathBuf,
        /// Frames the log lists.
        frames: usize,
        /// The configured count.
        count: usize,
    },
}

impl std::fmt::Display for OutError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::NotAFolder(p) => write!(f, "the output {} is a file, not a folder", p.display()),
            Self::Finished(p) => write!(f, "{} holds a finished recording (or dataset): set force to record over it", p.display()),
            Self::Unfinished(p) => {
                write!(f, "{} holds an unfinished recording: set resume to continue it, or force to start again", p.display())
            }
            Self::NotEmpty(p) => write!(f, "{} is not empty and holds no recording: give a new folder", p.display()),
            Self::BadLog { log, what } => write!(f, "{}: {what}: set force to record again", log.display()),
            Self::NoTemplate(p) => write!(f, "no face template: configure one, or make {}", p.display()),
            Self::TooMany { log, frames, count } => write!(f, "{} holds {frames} frames, more than the count {count}", log.display()),
        }
    }
}

impl std::error::Error for OutError {}

/// Checks `out` before anything is sent or changed: a finished recording is kept unless
/// `force`, an unfinished one needs `resume` (or `force`) and a log that [`check_log`] passes.
/// Returns the log entries to continue from.
fn check_out(cfg: &RecordConfig) -> Result<Vec<Entry>> {
    let out = &cfg.out;
    let index = out.join(layout::INDEX_FILE);
    let log = out.join(LOG_FILE);
    if out.exists() && !out.is_dir() {
        return Err(OutError::NotAFolder(out.clone()).into());
    }
    if cfg.force {
        return Ok(Vec::new());
    } else if index.exists() {
        return Err(OutError::Finished(out.clone()).into());
    } else if log.exists() {
        if !cfg.resume {
            return Err(OutError::Unfinished(out.clone()).into());
        }
        let entries = read_log(&log)?;
        check_log(out, &log, &entries, cfg.count)?;
        return Ok(entries);
    } else if out.is_dir() && std::fs::read_dir(out)?.any(|e| e.is_ok_and(|e| e.file_name() != layout::TEMPLATE_FILE)) {
        return Err(OutError::NotEmpty(out.clone()).into());
    }
    Ok(Vec::new())
}

/// Makes `out` ready once [`check_out`] passed: with `force`, the old recording goes.
fn prepare_out(cfg: &RecordConfig) -> Result<()> {
    let out = &cfg.out;
    if cfg.force {
        for f in [&out.join(layout::INDEX_FILE), &out.join(LOG_FILE), &out.join(layout::ANGLES_FILE)] {
            if f.exists() {
                std::fs::remove_file(f).with_context(|| format!("removing {}", f.display()))?;
            }
        }
        let frames = out.join("frames");
        if frames.is_dir() {
            std::fs::remove_dir_all(&frames).with_context(|| format!("removing {}", frames.display()))?;
        }
    }
    std::fs::create_dir_all(out.join("frames")).with_context(|| format!("creating {}", out.display()))?;
    Ok(())
}

/// The head angles a frame is kept with, as recorded and as read back: finite and inside the
/// Nao's joint range.
fn check_head(head: [f64; 2]) -> Result<()> {
    for (joint, a) in [(Joint::HeadYaw, head[0]), (Joint::HeadPitch, head[1])] {
        joint.validate(a as f32).map_err(|e| anyhow::anyhow!("head {e} (the Nao's joint range)"))?;
    }
    Ok(())
}

/// The log read back, held to what a recording writes: the k-th kept frame is
/// `frames/{k:06}.png` (so none missing, none twice, none outside the folder), its PNG is there,
/// its angles pass [`check_head`], and there are no more frames than `count`.
fn check_log(out: &Path, log: &Path, entries: &[Entry], count: usize) -> Result<()> {
    let mut k = 0usize;
    for e in entries {
        let Entry::Frame { file, head } = e else { continue };
        let want = format!("frames/{k:06}.png");
        if *file != want {
            let what = format!(
                "kept frame {} is {file:?}, a recording writes {want:?} (a frame missing, twice, or outside the folder)",
                k + 1
            );
            return Err(OutError::BadLog { log: log.to_path_buf(), what }.into());
        }
        check_head(*head).with_context(|| format!("{}: frame {file}", log.display()))?;
        if !out.join(file).is_file() {
            let what = format!("frame {file} is listed but {} is missing", out.join(file).display());
            return Err(OutError::BadLog { log: log.to_path_buf(), what }.into());
        }
        k += 1;
    }
    if k > count {
        return Err(OutError::TooMany { log: log.to_path_buf(), frames: k, count }.into());
    }
    Ok(())
}

/// Records `cfg.count` frames.
pub fn record(cfg: &RecordConfig) -> Result<Recorded> {
    let tpl = template(cfg)?;
    // Everything that can fail is checked before anything in --out changes and before the
    // banner: the folder and its log, the camera, the port.
    let done = check_out(cfg)?;
    let mut src = camera::open(
        &cfg.source,
        &SourceOptions { timeout: cfg.frame_timeout, ..SourceOptions::default() },
    )?;
    let mut session = Session::open(&cfg.port, cfg.baud)?;
    prepare_out(cfg)?;
    if cfg.progress {
        eprintln!(
            "recording {} frames (head within +-{} deg) into {}",
            cfg.count,
            cfg.range_deg,
            cfg.out.display()
        );
    }
    let tpl_path = cfg.out.join(layout::TEMPLATE_FILE);
    let same = |a: &Path| a.canonicalize().ok().is_some_and(|a| Some(a) == tpl_path.canonicalize().ok());
    if cfg.template.as_deref().is_some_and(|t| !same(t)) || !tpl_path.is_file() {
        fsio::write_with(&tpl_path, |p| tpl.save_with_format(p, image::ImageFormat::Png).map_err(Into::into))?;
    }
    let cropper = Cropper::new(tpl.clone(), CropMode::Subpixel);
    let mut log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(cfg.out.join(LOG_FILE))
        .with_context(|| format!("opening {}", cfg.out.join(LOG_FILE).display()))?;
    let mut frames: Vec<(String, [f64; 2])> = done
        .iter()
        .filter_map(|e| match e {
            Entry::Frame { file, head } => Some((file.clone(), *head)),
            Entry::Skip => None,
        })
        .collect();
    let mut rec = Recorded {
        frames: 0,
        resumed: frames.len(),
        skipped_no_face: 0,
        skipped_not_settled: 0,
        max_pose_error_deg: 0.0,
    };
    // The poses are one seeded sequence: a resumed run draws on where the last one stopped.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(cfg.seed);
    let range = cfg.range_deg.to_radians();
    let mut draw = move || [rng.gen_range(-range..=range), rng.gen_range(-range..=range)];
    for _ in 0..done.len() {
        draw();
    }
    let bar = cfg.progress.then(|| {
        let b = indicatif::ProgressBar::new(cfg.count as u64);
        b.set_style(
            indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} frames, {elapsed} (eta {eta}) {msg}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        b.set_position(frames.len() as u64);
        b
    });
    let mut tries = 0usize;
    let mut mcap = (cfg.mcap.is_some() || cfg.live.is_some()).then(|| {
        let l = crate::rosbag::session::SessionLog::default();
        let l = match &cfg.live {
            Some(v) => l.live(v.clone(), cfg.mcap.is_none()),
            None => l,
        };
        (l, std::time::Instant::now())
    });
    while frames.len() < cfg.count {
        tries += 1;
        if tries > MAX_TRIES_PER_FRAME * cfg.count {
            bail!(
                "{} poses tried for {} frames kept ({} without a face, {} not settled): check the \
                 camera and the template",
                tries - 1,
                frames.len(),
                rec.skipped_no_face,
                rec.skipped_not_settled
            );
        }
        let asked = draw();
        let head = match move_head(&mut session, asked, cfg.head_timeout)? {
            Some(h) => h,
            None => {
                rec.skipped_not_settled += 1;
                writeln!(log, "skip,not-settled,{:.10},{:.10}", asked[0], asked[1])?;
                continue;
            }
        };
        check_head(head).context("the board reported a head pose that no frame may be kept with")?;
        if let Some((l, t0)) = &mut mcap {
            let us = t0.elapsed().as_micros() as u64;
            l.joints(us, &["HeadYaw", "HeadPitch"], &head, &asked);
        }
        let err = (head[0] - asked[0]).abs().max((head[1] - asked[1]).abs()).to_degrees();
        rec.max_pose_error_deg = rec.max_pose_error_deg.max(err);
        let frame = grab(&mut src, head)?;
        let face = cropper.crop(&frame.grey).with_context(|| format!("frame {}", frame.name))?;
        let face_found = correlation(&face.grey, tpl.as_raw()) >= MIN_FACE_CORRELATION;
        if let Some((l, t0)) = &mut mcap {
            let label = if face_found { format!("frame {}", frames.len()) } else { "no face: skipped".into() };
            l.frame_labelled(t0.elapsed().as_micros() as u64, &frame.grey, &face, &label);
        }
        if !face_found {
            rec.skipped_no_face += 1;
            writeln!(log, "skip,no-face,{:.10},{:.10}", head[0], head[1])?;
            continue;
        }
        let file = format!("frames/{:06}.png", frames.len());
        let path = cfg.out.join(&file);
        fsio::write_with(&path, |p| frame.grey.save_with_format(p, image::ImageFormat::Png).map_err(Into::into))?;
        // Full precision, so that a resumed recording keeps the angles exactly.
        writeln!(log, "frame,{file},{},{}", head[0], head[1])?;
        log.flush()?;
        frames.push((file, head));
        rec.frames += 1;
        if let Some(b) = &bar {
            b.set_position(frames.len() as u64);
            b.set_message(format!("{} skipped", rec.skipped_no_face + rec.skipped_not_settled));
        }
    }
    if let Some(b) = &bar {
        b.finish();
    }
    if let (Some(p), Some((mut l, _))) = (&cfg.mcap, mcap) {
        l.close()?;
        crate::rosbag::session::write_logs(p, [&l])?;
    }
    finish(cfg, &frames, src.camera_controls())?;
    Ok(rec)
}

/// Asks for a head pose: `Some(reported angles)` once settled, `None` when the servos did not
/// settle in time; an error when the board refused it or did not answer. A board that has no
/// servo positions yet (just started: its bus has not answered a first read) is asked again
/// until `timeout` has passed.
pub fn move_head(s: &mut Session, head: [f64; 2], timeout: Duration) -> Result<Option<[f64; 2]>> {
    let deadline = std::time::Instant::now() + timeout;
    loop {
        s.send_message(&HostToBoard::MoveHead { yaw: head[0] as f32, pitch: head[1] as f32 })?;
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        let (msgs, ok) = s.wait_for(left, |m| {
            matches!(
                m,
                BoardToHost::HeadAt { .. }
                    | BoardToHost::Error { code: ErrorCode::HeadRefused | ErrorCode::HeadNotSettled, .. }
            )
        })?;
        return match msgs.last() {
            Some(BoardToHost::HeadAt { head }) if ok => Ok(Some([head[0] as f64, head[1] as f64])),
            Some(BoardToHost::Error { code: ErrorCode::HeadNotSettled, .. }) if ok => Ok(None),
            Some(BoardToHost::Error { code: ErrorCode::HeadRefused, detail: 1 })
                if ok && std::time::Instant::now() + NO_SERVOS_RETRY < deadline =>
            {
                std::thread::sleep(NO_SERVOS_RETRY);
                continue;
            }
            Some(BoardToHost::Error { code: ErrorCode::HeadRefused, detail }) if ok => bail!(
                "the board refused head pose ({:.3}, {:.3}) deg: {}",
                head[0].to_degrees(),
                head[1].to_degrees(),
                match detail {
                    0 => "outside the joint limits",
                    1 => "no servo positions (is the servo bus up?)",
                    2 => "a reach is in progress",
                    _ => "unknown reason",
                }
            ),
            _ => bail!("the board did not answer a head pose within {timeout:?} (does it speak host link protocol 4?)"),
        };
    }
}

/// How long to wait before asking a board without servo positions again.
const NO_SERVOS_RETRY: Duration = Duration::from_millis(50);

/// The next frame taken after the head settled at `head`.
fn grab(src: &mut Frames, head: [f64; 2]) -> Result<camera::Frame> {
    src.head_moved(head);
    src.discard_buffered();
    match src.next_frame()? {
        Some(f) => Ok(f),
        None => bail!("the camera ended before the recording was complete"),
    }
}

/// Writes the index and the angle table: the recording is then finished.
/// `controls`: the camera's held controls, stored with the recording (`camera_controls`).
fn finish(cfg: &RecordConfig, frames: &[(String, [f64; 2])], controls: Option<std::collections::BTreeMap<String, i32>>) -> Result<()> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x5e11_7e57);
    let n_test = (frames.len() as f64 * cfg.test_fraction).round() as usize;
    let mut order: Vec<usize> = (0..frames.len()).collect();
    for i in (1..order.len()).rev() {
        order.swap(i, rng.gen_range(0..=i));
    }
    let mut split = vec![Split::Train; frames.len()];
    for &i in &order[..n_test] {
        split[i] = Split::Test;
    }
    let mut angles = String::new();
    let records = frames
        .iter()
        .zip(split)
        .map(|((file, h), split)| {
            angles.push_str(&format!("{:.10},{:.10}\n", h[0], h[1]));
            FrameRecord { file: file.clone(), head_yaw: h[0], head_pitch: h[1], split, mark: None, seen_head: None }
        })
        .collect();
    let index = DatasetIndex {
        robot: "recorded".into(),
        seed: cfg.seed,
        width: msr_sim::body::WIDTH,
        height: msr_sim::body::HEIGHT,
        template: layout::TEMPLATE_FILE.into(),
        frames: records,
        camera_controls: controls,
        imperfections: match cfg.source {
            SourceConfig::Sim { camera, .. } if !camera.is_none() => Some(camera),
            _ => None,
        },
    };
    fsio::write(&cfg.out.join(layout::ANGLES_FILE), angles)?;
    fsio::write(&cfg.out.join(layout::INDEX_FILE), serde_json::to_vec_pretty(&index)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_held_camera_controls_are_stored_in_dataset_json_and_older_ones_load_without() {
        let d = tempfile::tempdir().unwrap();
        let cfg = RecordConfig::new("-", SourceConfig::Y4mStdin, 1, d.path());
        let frames = [("frames/000000.png".to_string(), [0.01, -0.02])];
        let held: std::collections::BTreeMap<String, i32> = [("exposure_absolute".into(), 156), ("gain".into(), 64)].into();
        finish(&cfg, &frames, Some(held.clone())).unwrap();
        let text = std::fs::read_to_string(d.path().join(layout::INDEX_FILE)).unwrap();
        let ix: DatasetIndex = serde_json::from_str(&text).unwrap();
        assert_eq!(ix.camera_controls, Some(held));
        assert!(text.contains("\"camera_controls\""), "{text}");
        // Without a held camera the field is left out, and a dataset.json without it loads.
        finish(&cfg, &frames, None).unwrap();
        let text = std::fs::read_to_string(d.path().join(layout::INDEX_FILE)).unwrap();
        assert!(!text.contains("camera_controls"), "{text}");
        let ix: DatasetIndex = serde_json::from_str(&text).unwrap();
        assert_eq!((ix.camera_controls, ix.frames.len()), (None, 1));
    }

    #[test]
    fn correlation_is_one_for_the_same_image_and_low_for_noise() {
        let a: Vec<u8> = (0..200u32).map(|i| (i * 7 % 251) as u8).collect();
        assert!((correlation(&a, &a) - 1.0).abs() < 1e-12);
        let b: Vec<u8> = a.iter().map(|v| 255 - v).collect();
        assert!((correlation(&a, &b) + 1.0).abs() < 1e-12);
        assert_eq!(correlation(&a, &[9; 200]), 0.0, "flat");
    }

    #[test]
    fn the_log_reads_back_and_a_cut_last_line_is_dropped() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join(LOG_FILE);
        std::fs::write(&p, "frame,frames/000000.png,0.01,-0.02\nskip,no-face,0.1,0.1\nframe,frames/0000").unwrap();
        let e = read_log(&p).unwrap();
        assert_eq!(
            e,
            vec![Entry::Frame { file: "frames/000000.png".into(), head: [0.01, -0.02] }, Entry::Skip]
        );
        std::fs::write(&p, "frame,x,notanumber,0\n").unwrap();
        assert!(read_log(&p).unwrap_err().to_string().contains("line 1"));
    }
}
