//! A rosbag2 recording (camera images and joint states) into the dataset layout that training
//! reads and recording writes (robot "recorded", a seeded split, full frames that
//! the loader crops with the template).
//!
//! Two passes over the bag. The first reads every message of the two topics: it checks the types
//! and encodings and finds a damaged file before anything is written, and it keeps the joint
//! states (small) and each image's stamp. Each image then gets the head angles interpolated
//! linearly at its header stamp, or is skipped: no joint state on both sides within the gap limit,
//! a joint state there that is not a number (never interpolated across), the head moving faster
//! than the speed limit there, or (second pass) an image that does not decode whole (a cut JPEG is
//! damaged, not a picture with grey rows) or has no face where the template looks. The second pass
//! decodes the kept images and writes them into a temporary folder beside the output folder,
//! renamed to it at the end: a failed import leaves nothing, and the temporary folders of
//! imports that were killed are removed by the next import beside them.
use super::msgs::{self, CompressedImage, Image, JointState};
use super::read::{Bag, Topic};
use crate::data::crop::{self, CropMode, Cropper};
use anyhow::{bail, Context, Result};
use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::{DynamicImage, GrayImage, ImageEncoder, RgbImage};
use msr_sim::layout::{self, DatasetIndex, FrameRecord, Split};
use rand::{Rng, SeedableRng};
use std::path::{Path, PathBuf};

/// What to import, and what to keep.
#[derive(Clone, Debug, PartialEq)]
pub struct ImportConfig {
    /// The bag folder, or one `.mcap` / `.db3` file.
    pub bag: PathBuf,
    /// The camera topic (`sensor_msgs/msg/Image` or `sensor_msgs/msg/CompressedImage`).
    pub image_topic: String,
    /// The `sensor_msgs/msg/JointState` topic the head angles come from.
    pub joints_topic: String,
    /// The names of the yaw and pitch joints in the JointState messages.
    pub joint_names: [String; 2],
    /// The face template (grey PNG) that finds the face in each image.
    pub template: PathBuf,
    /// The dataset folder to make: new, or empty.
    pub out: PathBuf,
    /// Images taken while either head joint moved faster than this (rad/s) are skipped.
    pub max_speed: f64,
    /// Images without a joint state this close (ns) before and after their stamp are skipped.
    pub max_gap_ns: u64,
    /// Share of the kept frames drawn for the test split (0 to 1).
    pub test_fraction: f64,
    /// Seed of the train/test split.
    pub seed: u64,
    /// Shows a progress bar on stderr.
    pub progress: bool,
}

impl ImportConfig {
    /// An import with the defaults: joints `HeadYaw` and `HeadPitch`, at most 5 deg/s of head
    /// speed, a joint state within 100 ms on both sides, a fifth of the frames for testing,
    /// seed 0.
    pub fn new(bag: &Path, image_topic: &str, joints_topic: &str, template: &Path, out: &Path) -> ImportConfig {
        ImportConfig {
            bag: bag.into(),
            image_topic: image_topic.into(),
            joints_topic: joints_topic.into(),
            joint_names: ["HeadYaw".into(), "HeadPitch".into()],
            template: template.into(),
            out: out.into(),
            max_speed: 5f64.to_radians(),
            max_gap_ns: 100_000_000,
            test_fraction: 0.2,
            seed: 0,
            progress: false,
        }
    }
}

/// What an import did.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Imported {
    /// Messages on the image topic.
    pub images: usize,
    /// Messages on the joint state topic.
    pub joint_states: usize,
    /// Images kept as frames of the dataset.
    pub frames: usize,
    /// Frames in the train split.
    pub train: usize,
    /// Frames in the test split.
    pub test: usize,
    /// Images taken while the head moved faster than the speed limit.
    pub skipped_moving: usize,
    /// Images without a joint state within the gap limit on both sides of their stamp.
    pub skipped_no_joint_state: usize,
    /// Images whose head pose would come from a joint state that is not a number.
    pub skipped_invalid_joint_state: usize,
    /// Images that do not decode whole (a cut or damaged JPEG or PNG).
    pub skipped_damaged: usize,
    /// Images whose crop does not look like the template (no face where it looks).
    pub skipped_no_face: usize,
    /// What was wrong with the first damaged image.
    pub first_damage: Option<String>,
    /// Wall-clock time of the import, seconds.
    pub seconds: f64,
}

/// Why an image is not kept.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Skip {
    /// The head moved faster than the speed limit around the image's stamp.
    Moving,
    /// No joint state within the gap limit before and after the stamp.
    NoJointState,
    /// A joint state around the stamp holds a head angle that is not a number.
    InvalidJointState,
}

/// Head angles at `t` from joint samples sorted by time (no two at the same time; `None` a
/// sample whose head angles are not numbers): linear between the samples around `t`, each
/// within `max_gap` of it; `Err` when the head moved faster than `max_speed` (either joint,
/// rad/s) on a segment touching `t`, or when a sample the pose would come from is not valid (the
/// pose is never taken across one).
pub fn head_at(samples: &[(u64, Option<[f64; 2]>)], t: u64, max_gap: u64, max_speed: f64) -> Result<[f64; 2], Skip> {
    let k = samples.partition_point(|s| s.0 < t);
    // The speed between two valid samples; a segment to an invalid one says nothing of it.
    let speed = |a: usize, b: usize| match (samples[a], samples[b]) {
        ((ta, Some(qa)), (tb, Some(qb))) => {
            let dt = (tb - ta) as f64 * 1e-9;
            (qb[0] - qa[0]).abs().max((qb[1] - qa[1]).abs()) / dt
        }
        _ => 0.0,
    };
    if k < samples.len() && samples[k].0 == t {
        let Some(q) = samples[k].1 else { return Err(Skip::InvalidJointState) };
        let mut v: f64 = 0.0;
        if k > 0 && t - samples[k - 1].0 <= max_gap {
            v = v.max(speed(k - 1, k));
        }
        if k + 1 < samples.len() && samples[k + 1].0 - t <= max_gap {
            v = v.max(speed(k, k + 1));
        }
        return if v > max_speed { Err(Skip::Moving) } else { Ok(q) };
    }
    if k == 0 || k == samples.len() {
        return Err(Skip::NoJointState);
    }
    let ((t0, q0), (t1, q1)) = (samples[k - 1], samples[k]);
    if t - t0 > max_gap || t1 - t > max_gap {
        return Err(Skip::NoJointState);
    }
    let (Some(q0), Some(q1)) = (q0, q1) else { return Err(Skip::InvalidJointState) };
    if speed(k - 1, k) > max_speed {
        return Err(Skip::Moving);
    }
    let a = (t - t0) as f64 / (t1 - t0) as f64;
    Ok([q0[0] + a * (q1[0] - q0[0]), q0[1] + a * (q1[1] - q0[1])])
}

/// A message's time: its header stamp, or the bag's log time when the stamp was left at zero.
fn stamp(h: &msgs::Header, log_time: u64) -> u64 {
    match h.stamp.to_ns() {
        Some(0) | None => log_time,
        Some(t) => t,
    }
}

/// Encodings of `sensor_msgs/msg/Image` read here.
pub const IMAGE_ENCODINGS: [&str; 7] = ["mono8", "rgb8", "bgr8", "yuv422", "uyvy", "yuv422_yuy2", "yuyv"];

/// Checks an Image's fields without decoding it.
fn check_image(m: &Image) -> Result<()> {
    let bpp = match m.encoding.as_str() {
        "mono8" => 1,
        "rgb8" | "bgr8" => 3,
        "yuv422" | "uyvy" | "yuv422_yuy2" | "yuyv" => 2,
        e => bail!("image encoding {e:?} is not read (read: {})", IMAGE_ENCODINGS.join(", ")),
    };
    if m.width == 0 || m.height == 0 || m.width > 16384 || m.height > 16384 {
        bail!("image of {}x{} pixels", m.width, m.height);
    }
    if bpp == 2 && m.width % 2 == 1 {
        bail!("{} image of odd width {}", m.encoding, m.width);
    }
    let row = m.width as usize * bpp;
    if (m.step as usize) < row || m.data.len() < m.step as usize * (m.height as usize - 1) + row {
        bail!(
            "{}x{} {} image with step {} holds {} bytes, too few",
            m.width,
            m.height,
            m.encoding,
            m.step,
            m.data.len()
        );
    }
    Ok(())
}

/// The compressed formats read: `jpeg` or `png`, alone or as image_transport writes them
/// (`bgr8; jpeg compressed bgr8`).
fn compressed_format(format: &str) -> Result<image::ImageFormat> {
    let f = format.to_ascii_lowercase();
    if f.contains("jpeg") || f.contains("jpg") {
        Ok(image::ImageFormat::Jpeg)
    } else if f.contains("png") {
        Ok(image::ImageFormat::Png)
    } else {
        bail!("compressed image format {format:?} is not read (read: jpeg, png)")
    }
}

/// An Image as the frame to store: grey for mono8 and YUV (the luma, which is the grey), RGB for
/// rgb8 and bgr8.
pub fn decode_image(m: &Image) -> Result<DynamicImage> {
    check_image(m)?;
    let (w, h, step) = (m.width as usize, m.height as usize, m.step as usize);
    let row = |y: usize| &m.data[y * step..];
    Ok(match m.encoding.as_str() {
        "mono8" => DynamicImage::ImageLuma8(GrayImage::from_fn(w as u32, h as u32, |x, y| image::Luma([row(y as usize)[x as usize]]))),
        "rgb8" | "bgr8" => {
            let bgr = m.encoding == "bgr8";
            DynamicImage::ImageRgb8(RgbImage::from_fn(w as u32, h as u32, |x, y| {
                let p = &row(y as usize)[3 * x as usize..];
                image::Rgb(if bgr { [p[2], p[1], p[0]] } else { [p[0], p[1], p[2]] })
            }))
        }
        // UYVY: U Y0 V Y1; YUYV: Y0 U Y1 V.
        e => {
            let y_at = if e == "yuv422" || e == "uyvy" { 1 } else { 0 };
            DynamicImage::ImageLuma8(GrayImage::from_fn(w as u32, h as u32, |x, y| {
                image::Luma([row(y as usize)[2 * x as usize + y_at]])
            }))
        }
    })
}

/// A JPEG decoded whole, or an error: the decoder's strict mode refuses data that ends early or
/// holds a marker where none belongs (its lenient mode, `image`'s, fills what is missing with
/// grey).
fn decode_jpeg(data: &[u8]) -> Result<DynamicImage> {
    use zune_core::bytestream::ZCursor;
    use zune_core::colorspace::ColorSpace;
    use zune_core::options::DecoderOptions;
    let opts = DecoderOptions::default().set_strict_mode(true).set_max_width(16384).set_max_height(16384);
    let mut d = zune_jpeg::JpegDecoder::new_with_options(ZCursor::new(data), opts);
    // The decoder's messages may span lines: one line each.
    let err = |e: zune_jpeg::errors::DecodeErrors| anyhow::anyhow!("{}", format!("{e:?}").split_whitespace().collect::<Vec<_>>().join(" "));
    d.decode_headers().map_err(err)?;
    let grey = d.input_colorspace() == Some(ColorSpace::Luma);
    d.set_options(opts.jpeg_set_out_colorspace(if grey { ColorSpace::Luma } else { ColorSpace::RGB }));
    let px = d.decode().map_err(err)?;
    let info = d.info().context("no image size after decoding")?;
    let (w, h) = (info.width as u32, info.height as u32);
    let img = if grey {
        GrayImage::from_raw(w, h, px).map(DynamicImage::ImageLuma8)
    } else {
        RgbImage::from_raw(w, h, px).map(DynamicImage::ImageRgb8)
    };
    img.context("the decoder gave fewer pixels than its image size")
}

/// A CompressedImage (JPEG or PNG) decoded whole: grey stays grey, anything else becomes RGB.
pub fn decode_compressed(m: &CompressedImage) -> Result<DynamicImage> {
    let f = compressed_format(&m.format)?;
    let img = match f {
        image::ImageFormat::Jpeg => decode_jpeg(&m.data),
        _ => image::load_from_memory_with_format(&m.data, f).map_err(anyhow::Error::from),
    }
    .with_context(|| format!("decoding a {} image", m.format))?;
    Ok(match img {
        DynamicImage::ImageLuma8(_) | DynamicImage::ImageRgb8(_) => img,
        other => DynamicImage::ImageRgb8(other.to_rgb8()),
    })
}

/// The image topic's message type, checked.
fn find_topics(topics: &[Topic], cfg: &ImportConfig) -> Result<bool> {
    let list = |ty: &[&str]| {
        let v: Vec<String> = topics.iter().filter(|t| ty.contains(&t.type_name.as_str())).map(|t| t.name.clone()).collect();
        if v.is_empty() { "none".to_string() } else { v.join(", ") }
    };
    let img_types = [msgs::IMAGE, msgs::COMPRESSED_IMAGE];
    let compressed = match topics.iter().find(|t| t.name == cfg.image_topic) {
        None => bail!("bag {} has no topic {} (image topics: {})", cfg.bag.display(), cfg.image_topic, list(&img_types)),
        Some(t) if t.type_name == msgs::IMAGE => false,
        Some(t) if t.type_name == msgs::COMPRESSED_IMAGE => true,
        Some(t) => bail!("topic {} is a {}, not a {} or {}", t.name, t.type_name, msgs::IMAGE, msgs::COMPRESSED_IMAGE),
    };
    match topics.iter().find(|t| t.name == cfg.joints_topic) {
        None => bail!(
            "bag {} has no topic {} (joint state topics: {})",
            cfg.bag.display(),
            cfg.joints_topic,
            list(&[msgs::JOINT_STATE])
        ),
        Some(t) if t.type_name != msgs::JOINT_STATE => bail!("topic {} is a {}, not a {}", t.name, t.type_name, msgs::JOINT_STATE),
        Some(_) => {}
    }
    Ok(compressed)
}

/// Removes the temporary folders (`.NAME.tmpPID`) that imports into `out` left beside it when
/// they were killed: those whose process is gone. A folder of a running import is left alone.
fn remove_stale_temps(parent: &Path, name: &str) {
    let prefix = format!(".{name}.tmp");
    let Ok(entries) = std::fs::read_dir(parent) else { return };
    for e in entries.flatten() {
        let file = e.file_name();
        let Some(pid) = file.to_str().and_then(|f| f.strip_prefix(prefix.as_str())).and_then(|p| p.parse::<i32>().ok()) else {
            continue;
        };
        if pid <= 0 || pid as u32 == std::process::id() || !e.file_type().is_ok_and(|t| t.is_dir()) {
            continue;
        }
        // SAFETY: signal 0 only asks whether the process exists; nothing is sent.
        let gone = unsafe { libc::kill(pid, 0) } == -1 && std::io::Error::last_os_error().raw_os_error() == Some(libc::ESRCH);
        if gone {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

/// Removes a folder when dropped, unless kept.
struct TempDir(Option<PathBuf>);

impl Drop for TempDir {
    fn drop(&mut self) {
        if let Some(p) = &self.0 {
            let _ = std::fs::remove_dir_all(p);
        }
    }
}

/// No joint state of the bag names both head joints of `joint_names`: the bag calls them
/// otherwise. The command line says which flag names them.
#[derive(Debug, Clone, PartialEq)]
pub struct UnnamedJoints {
    /// The joint-state topic.
    pub topic: String,
    /// The yaw and pitch names looked for.
    pub names: [String; 2],
    /// The joint names the topic's messages hold, comma-separated (`none` if none).
    pub seen: String,
}

impl std::fmt::Display for UnnamedJoints {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let [yaw, pitch] = &self.names;
        write!(
            f,
            "no message on {} names both {yaw} and {pitch} (names seen: {}): set joint_names to the bag's yaw and pitch joints",
            self.topic, self.seen
        )
    }
}

impl std::error::Error for UnnamedJoints {}

/// Imports the bag. Nothing is written unless the whole import succeeds.
pub fn import(cfg: &ImportConfig) -> Result<Imported> {
    let t_start = std::time::Instant::now();
    if cfg.out.exists() && !(cfg.out.is_dir() && std::fs::read_dir(&cfg.out)?.next().is_none()) {
        bail!("the output folder {} exists and is not empty: give a new one", cfg.out.display());
    }
    let tpl = crop::load_grey(&cfg.template).context("the face template")?;
    let cropper = Cropper::new(tpl.clone(), CropMode::Subpixel);
    let bag = Bag::open(&cfg.bag)?;
    let topics = bag.topics()?;
    let compressed = find_topics(&topics, cfg)?;

    // Pass 1: joint states, image stamps, every image checked.
    let mut joints: Vec<(u64, Option<[f64; 2]>)> = Vec::new();
    let mut joint_msgs = 0usize;
    let mut named_without_positions = 0usize;
    let mut names_seen: Vec<String> = Vec::new();
    let mut stamps: Vec<u64> = Vec::new();
    let [yaw_name, pitch_name] = &cfg.joint_names;
    bag.for_each(&[cfg.image_topic.as_str(), cfg.joints_topic.as_str()], &mut |topic, _, log_time, data| {
        if topic == cfg.joints_topic {
            let m: JointState = msgs::decode(data).with_context(|| format!("a message on {topic}"))?;
            joint_msgs += 1;
            let t = stamp(&m.header, log_time);
            // A JointState's arrays are as long as its names, or empty (not measured).
            if !m.position.is_empty() && m.position.len() != m.name.len() {
                bail!(
                    "joint state {joint_msgs} on {topic} (stamp {t} ns) has {} names and {} positions: a JointState's \
                     positions are one per name, or none",
                    m.name.len(),
                    m.position.len()
                );
            }
            let at = |n: &str| m.name.iter().position(|x| x.as_str() == n).and_then(|i| m.position.get(i).copied());
            let named = |n: &str| m.name.iter().any(|x| x.as_str() == n);
            match (at(yaw_name), at(pitch_name)) {
                (Some(y), Some(p)) => joints.push((t, (y.is_finite() && p.is_finite()).then_some([y, p]))),
                _ if named(yaw_name) && named(pitch_name) => named_without_positions += 1,
                _ => {
                    if names_seen.is_empty() {
                        names_seen = m.name.clone();
                    }
                }
            }
        } else if compressed {
            let m: CompressedImage = msgs::decode(data).with_context(|| format!("a message on {topic}"))?;
            compressed_format(&m.format).with_context(|| format!("topic {topic}"))?;
            stamps.push(stamp(&m.header, log_time));
        } else {
            let m: Image = msgs::decode(data).with_context(|| format!("a message on {topic}"))?;
            check_image(&m).with_context(|| format!("topic {topic}"))?;
            stamps.push(stamp(&m.header, log_time));
        }
        Ok(())
    })?;
    if stamps.is_empty() {
        bail!("topic {} has no messages", cfg.image_topic);
    }
    if joints.is_empty() && named_without_positions > 0 {
        bail!(
            "the {named_without_positions} messages on {} that name {yaw_name} and {pitch_name} carry no positions",
            cfg.joints_topic
        );
    }
    if joints.iter().all(|j| j.1.is_none()) && !joints.is_empty() {
        bail!(
            "every joint state on {} holds a head angle that is not a number ({} messages)",
            cfg.joints_topic,
            joints.len()
        );
    }
    if joints.is_empty() {
        let seen = if names_seen.is_empty() { "none".into() } else { names_seen.join(", ") };
        return Err(UnnamedJoints { topic: cfg.joints_topic.clone(), names: [yaw_name.to_string(), pitch_name.to_string()], seen }.into());
    }
    joints.sort_by_key(|j| j.0);
    // The last of samples with the same stamp.
    joints.reverse();
    joints.dedup_by_key(|j| j.0);
    joints.reverse();
    let heads: Vec<Result<[f64; 2], Skip>> = stamps.iter().map(|&t| head_at(&joints, t, cfg.max_gap_ns, cfg.max_speed)).collect();
    let skipped = |why: Skip| heads.iter().filter(|h| **h == Err(why)).count();
    let mut done = Imported {
        images: stamps.len(),
        joint_states: joint_msgs,
        frames: 0,
        train: 0,
        test: 0,
        skipped_moving: skipped(Skip::Moving),
        skipped_no_joint_state: skipped(Skip::NoJointState),
        skipped_invalid_joint_state: skipped(Skip::InvalidJointState),
        skipped_damaged: 0,
        skipped_no_face: 0,
        first_damage: None,
        seconds: 0.0,
    };

    // Pass 2: the kept images into a temporary folder.
    let name = cfg.out.file_name().map_or("out".into(), |n| n.to_string_lossy().into_owned());
    let parent = cfg.out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    std::fs::create_dir_all(parent).with_context(|| format!("cannot create {}", parent.display()))?;
    remove_stale_temps(parent, &name);
    let tmp = parent.join(format!(".{name}.tmp{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(tmp.join("frames")).with_context(|| format!("cannot create {}", tmp.display()))?;
    let mut guard = TempDir(Some(tmp.clone()));
    let bar = cfg.progress.then(|| {
        let b = indicatif::ProgressBar::new(stamps.len() as u64);
        b.set_style(
            indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} images, {elapsed} (eta {eta}) {msg}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        b
    });
    let mut i = 0usize;
    let mut size: Option<(u32, u32)> = None;
    let mut frames: Vec<(String, [f64; 2])> = Vec::new();
    let mut first_damage: Option<String> = None;
    bag.for_each(&[cfg.image_topic.as_str()], &mut |topic, _, _, data| {
        let k = i;
        i += 1;
        if let Some(b) = &bar {
            b.inc(1);
        }
        let Some(Ok(head)) = heads.get(k).copied() else { return Ok(()) };
        let img = if compressed {
            let m: CompressedImage = msgs::decode(data).with_context(|| format!("image {k} on {topic}"))?;
            match decode_compressed(&m) {
                Ok(img) => img,
                // A damaged picture is no frame of the training set: counted, and the rest go on.
                Err(e) => {
                    if done.skipped_damaged == 0 {
                        let why = format!("{e:#}").split_whitespace().collect::<Vec<_>>().join(" ");
                        first_damage = Some(format!("image {k} on {topic}: {why}"));
                    }
                    done.skipped_damaged += 1;
                    return Ok(());
                }
            }
        } else {
            decode_image(&msgs::decode(data)?).with_context(|| format!("image {k} on {topic}"))?
        };
        let s = (img.width(), img.height());
        if *size.get_or_insert(s) != s {
            bail!("image {k} on {topic} is {}x{}, the first was {}x{}", s.0, s.1, size.unwrap().0, size.unwrap().1);
        }
        let grey = crop::to_grey(&img);
        let face = cropper.crop(&grey).with_context(|| format!("image {k} on {topic}"))?;
        if crate::record::correlation(&face.grey, tpl.as_raw()) < crate::record::MIN_FACE_CORRELATION {
            done.skipped_no_face += 1;
            return Ok(());
        }
        let file = format!("frames/{:06}.png", frames.len());
        write_png(&tmp.join(&file), &img)?;
        frames.push((file, head));
        if let Some(b) = &bar {
            b.set_message(format!("{} kept", frames.len()));
        }
        Ok(())
    })?;
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    if i != stamps.len() {
        bail!("the bag changed while it was read ({} images, then {i})", stamps.len());
    }
    done.first_damage = first_damage;
    if frames.is_empty() {
        bail!(
            "no image kept of {}: {} while the head moved, {} without a joint state, {} with a joint state that is not \
             a number, {} damaged{}, {} without a face",
            done.images,
            done.skipped_moving,
            done.skipped_no_joint_state,
            done.skipped_invalid_joint_state,
            done.skipped_damaged,
            done.first_damage.as_ref().map_or(String::new(), |d| format!(" ({d})")),
            done.skipped_no_face
        );
    }
    let (w, h) = size.expect("a frame was kept");
    let split = split(frames.len(), cfg.test_fraction, cfg.seed);
    let mut angles = String::new();
    let records: Vec<FrameRecord> = frames
        .iter()
        .zip(&split)
        .map(|((file, q), &split)| {
            angles.push_str(&format!("{:.10},{:.10}\n", q[0], q[1]));
            FrameRecord { file: file.clone(), head_yaw: q[0], head_pitch: q[1], split, mark: None, seen_head: None }
        })
        .collect();
    done.frames = frames.len();
    done.test = split.iter().filter(|s| **s == Split::Test).count();
    done.train = done.frames - done.test;
    let index = DatasetIndex {
        robot: "recorded".into(),
        seed: cfg.seed,
        width: w,
        height: h,
        template: layout::TEMPLATE_FILE.into(),
        frames: records,
        camera_controls: None,
        imperfections: None,
    };
    write_png(&tmp.join(layout::TEMPLATE_FILE), &DynamicImage::ImageLuma8(tpl))?;
    std::fs::write(tmp.join(layout::ANGLES_FILE), angles).with_context(|| format!("cannot write in {}", tmp.display()))?;
    std::fs::write(tmp.join(layout::INDEX_FILE), serde_json::to_vec_pretty(&index)?)
        .with_context(|| format!("cannot write in {}", tmp.display()))?;
    if cfg.out.is_dir() {
        std::fs::remove_dir(&cfg.out).with_context(|| format!("cannot replace the empty folder {}", cfg.out.display()))?;
    }
    std::fs::rename(&tmp, &cfg.out).with_context(|| format!("cannot write {}", cfg.out.display()))?;
    guard.0 = None;
    done.seconds = t_start.elapsed().as_secs_f64();
    Ok(done)
}

/// The train/test split: `round(n * test_fraction)` frames drawn for the test split by a seeded
/// shuffle (as `msr record` draws its split).
pub fn split(n: usize, test_fraction: f64, seed: u64) -> Vec<Split> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x5e11_7e57);
    let n_test = (n as f64 * test_fraction).round() as usize;
    let mut order: Vec<usize> = (0..n).collect();
    for i in (1..order.len()).rev() {
        order.swap(i, rng.gen_range(0..=i));
    }
    let mut s = vec![Split::Train; n];
    for &i in &order[..n_test.min(n)] {
        s[i] = Split::Test;
    }
    s
}

/// PNG with fast compression, as `msr dataset` writes frames.
fn write_png(path: &Path, img: &DynamicImage) -> Result<()> {
    let mut buf = Vec::new();
    PngEncoder::new_with_quality(&mut buf, CompressionType::Fast, FilterType::Sub)
        .write_image(img.as_bytes(), img.width(), img.height(), img.color().into())
        .with_context(|| format!("encoding {}", path.display()))?;
    std::fs::write(path, buf).with_context(|| format!("cannot write {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    #[test]
    fn head_angles_interpolate_and_skips_follow_the_limits() {
        // Still at (0.1, 0) until 20 ms, then a move of 0.01 rad in 20 ms (0.5 rad/s).
        let s = [(0, Some([0.1, 0.0])), (20 * MS, Some([0.1, 0.0])), (40 * MS, Some([0.11, 0.0])), (200 * MS, Some([0.11, 0.0]))];
        assert_eq!(head_at(&s, 10 * MS, 50 * MS, 0.1), Ok([0.1, 0.0]));
        assert_eq!(head_at(&s, 0, 50 * MS, 0.1), Ok([0.1, 0.0]), "a sample's own time");
        assert_eq!(head_at(&s, 30 * MS, 50 * MS, 0.1), Err(Skip::Moving));
        let q = head_at(&s, 30 * MS, 50 * MS, 1.0).unwrap();
        assert!((q[0] - 0.105).abs() < 1e-12, "{q:?}");
        assert_eq!(head_at(&s, 20 * MS, 50 * MS, 0.1), Err(Skip::Moving), "a move starts at this sample");
        assert_eq!(head_at(&s, 120 * MS, 50 * MS, 0.1), Err(Skip::NoJointState), "80 ms from both samples");
        assert_eq!(head_at(&s, 120 * MS, 100 * MS, 0.1), Ok([0.11, 0.0]));
        assert_eq!(head_at(&s, 201 * MS, 100 * MS, 0.1), Err(Skip::NoJointState), "after the last");
    }

    #[test]
    fn no_pose_is_taken_across_an_invalid_joint_state() {
        // Valid at 0 and 40 ms, not a number at 20 ms: nothing between 0 and 40 ms is
        // interpolated (from 0 to 40 ms would say 0.05 at 20 ms), and no move is blamed.
        let s = [(0, Some([0.0, 0.0])), (20 * MS, None), (40 * MS, Some([0.1, 0.0]))];
        assert_eq!(head_at(&s, 10 * MS, 50 * MS, 0.1), Err(Skip::InvalidJointState));
        assert_eq!(head_at(&s, 20 * MS, 50 * MS, 0.1), Err(Skip::InvalidJointState));
        assert_eq!(head_at(&s, 30 * MS, 50 * MS, 0.1), Err(Skip::InvalidJointState));
        // A valid sample's own time: its neighbour's invalid state says nothing of a move.
        assert_eq!(head_at(&s, 0, 50 * MS, 0.1), Ok([0.0, 0.0]));
        assert_eq!(head_at(&s, 40 * MS, 50 * MS, 0.1), Ok([0.1, 0.0]));
    }

    #[test]
    fn a_cut_jpeg_is_an_error_not_grey_rows() {
        let img = RgbImage::from_fn(64, 48, |x, y| image::Rgb([(x * 4) as u8, (y * 5) as u8, 90]));
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90).encode_image(&img).unwrap();
        let m = |data: Vec<u8>| CompressedImage { format: "jpeg".into(), data, ..Default::default() };
        let whole = decode_compressed(&m(jpeg.clone())).unwrap();
        assert_eq!((whole.width(), whole.height()), (64, 48));
        for cut in [jpeg.len() * 85 / 100, jpeg.len() / 2, jpeg.len() / 3] {
            assert!(decode_compressed(&m(jpeg[..cut].to_vec())).is_err(), "cut to {cut} of {} bytes", jpeg.len());
        }
    }

    #[test]
    fn yuv_gives_the_luma_and_bgr_is_swapped() {
        let img = |enc: &str, data: Vec<u8>| Image { height: 1, width: 2, encoding: enc.into(), step: data.len() as u32, data, ..Default::default() };
        let g = decode_image(&img("uyvy", vec![9, 10, 8, 20])).unwrap();
        assert_eq!(g.as_bytes(), &[10, 20]);
        let g = decode_image(&img("yuyv", vec![10, 9, 20, 8])).unwrap();
        assert_eq!(g.as_bytes(), &[10, 20]);
        let c = decode_image(&img("bgr8", vec![1, 2, 3, 4, 5, 6])).unwrap();
        assert_eq!(c.as_bytes(), &[3, 2, 1, 6, 5, 4]);
        let e = decode_image(&img("rgb16", vec![0; 12])).unwrap_err().to_string();
        assert!(e.contains("rgb16") && e.contains("mono8"), "{e}");
        let e = decode_image(&img("rgb8", vec![0; 5])).unwrap_err().to_string();
        assert!(e.contains("too few"), "{e}");
        assert!(compressed_format("bgr8; jpeg compressed bgr8").is_ok());
        assert!(compressed_format("tiff").is_err());
    }

    #[test]
    fn the_split_is_seeded_and_sized() {
        let a = split(100, 0.2, 3);
        assert_eq!(a.iter().filter(|s| **s == Split::Test).count(), 20);
        assert_eq!(a, split(100, 0.2, 3));
        assert_ne!(a, split(100, 0.2, 4));
        assert!(split(10, 0.0, 0).iter().all(|s| *s == Split::Train));
    }
}
