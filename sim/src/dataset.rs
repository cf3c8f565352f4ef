//! Writes a mirror dataset in the layout of [`crate::layout`]: the paper's protocol by default
//! (1300 frames, head angles uniform in +-5 degrees, 80/20 split, marks on the test split only),
//! plus reach training pairs made by the IK. Deterministic: a seed gives the same bytes.
use crate::body::{self, BodyPose};
use crate::kin;
use crate::imperfect::Imperfections;
use crate::light::LightMode;
use crate::layout::{self, DatasetIndex, FrameRecord, MarkRecord, Split};
use crate::marks::Mark;
use crate::render::{Renderer, Variation};
use crate::Robot;
use anyhow::{bail, Context, Result};
use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::ImageEncoder;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::io::Write;
use std::path::Path;

/// Marks whose mean grey contrast on the face is below this are redrawn in another colour
/// (a red mark on the red cap would be invisible in grey, to the method and to a person).
pub const MIN_MARK_CONTRAST: f32 = 20.0;

/// What stands in front of the camera.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DatasetScene {
    /// The robot's own mirror image: the paper's dataset.
    #[default]
    Mirror,
    /// Another robot of the same look where the mirror image would be, its head at a pose of
    /// its own (drawn from the same range as ours, independently), marks on its face: the face
    /// does not follow the recorded head angles. Not for training; for measuring what a
    /// decoder of the own image makes of another's face (the self gate's premise).
    /// Each frame's draws for our head, the split and the mark are the mirror dataset's of the
    /// same seed.
    Other,
}

#[derive(Clone, Debug, PartialEq)]
/// What a synthetic dataset holds and how it is drawn.
pub struct DatasetConfig {
    /// The robot in the mirror.
    pub robot: Robot,
    /// Number of frames.
    pub count: usize,
    /// Seed of every random draw.
    pub seed: u64,
    /// Head angles are uniform in +-this, radians.
    pub max_head_angle: f64,
    /// Share of frames in the test split.
    pub test_fraction: f64,
    /// Reach training pairs to make with the IK (0 for none).
    pub reach_pairs: usize,
    /// Share of test frames left without a mark. The paper marks every test image; a few
    /// unmarked ones are what false-alarm rates and image-level AUROC are measured on.
    pub unmarked_test_fraction: f64,
    /// What stands in front of the camera.
    pub scene: DatasetScene,
    /// How the frames are lit: the calibrated light (the paper's session) or a light of
    /// their own per frame (`crate::light::Light::varied`).
    pub light: LightMode,
    /// What the camera does to each frame ([`Imperfections`]; `NONE`: the frames as rendered,
    /// their bytes unchanged), its noise drawn from the frame's own seed.
    pub camera: Imperfections,
}

impl DatasetConfig {
    /// The paper's protocol for one robot.
    pub fn paper(robot: Robot, seed: u64) -> DatasetConfig {
        DatasetConfig {
            robot,
            count: 1300,
            seed,
            max_head_angle: 5f64.to_radians(),
            test_fraction: 0.2,
            reach_pairs: 100,
            unmarked_test_fraction: 0.2,
            scene: DatasetScene::Mirror,
            light: LightMode::Fixed,
            camera: Imperfections::NONE,
        }
    }

    fn check(&self) -> Result<()> {
        if self.count == 0 || self.count > 1_000_000 {
            bail!("frame count must be 1..=1000000, got {}", self.count);
        }
        if !(0.0..=1.0).contains(&self.test_fraction) {
            bail!("test fraction must be in 0..=1, got {}", self.test_fraction);
        }
        if !(0.0..=1.0).contains(&self.unmarked_test_fraction) {
            bail!("unmarked test fraction must be in 0..=1, got {}", self.unmarked_test_fraction);
        }
        let lim = body::MAX_DATASET_HEAD_ANGLE;
        if !(self.max_head_angle.is_finite() && (0.0..=lim).contains(&self.max_head_angle)) {
            bail!("head angle range must be in 0..={lim} rad, got {}", self.max_head_angle);
        }
        if self.reach_pairs > 100_000 {
            bail!("at most 100000 reach pairs, got {}", self.reach_pairs);
        }
        Ok(())
    }
}

/// One frame's parameters, drawn before rendering so that the split does not change the draws.
struct Plan {
    yaw: f64,
    pitch: f64,
    var: Variation,
    split: Split,
    marked: bool,
    rng_seed: u64,
    /// The other robot's head (yaw, pitch), in the other scene.
    seen: Option<[f64; 2]>,
}

/// Writes the dataset into `out` (created if missing; existing files of the layout are
/// overwritten). Returns the index that was written.
pub fn write_dataset(cfg: &DatasetConfig, out: &Path) -> Result<DatasetIndex> {
    write_dataset_with(cfg, out, &mut |_, _| {})
}

/// [`write_dataset`], telling `progress(frames written, bytes written)` after each frame.
pub fn write_dataset_with(
    cfg: &DatasetConfig,
    out: &Path,
    progress: &mut dyn FnMut(usize, u64),
) -> Result<DatasetIndex> {
    cfg.check()?;
    let mut written = 0u64;
    std::fs::create_dir_all(out.join("frames")).with_context(|| format!("creating {}", out.display()))?;
    std::fs::create_dir_all(out.join("masks"))?;
    let renderer = Renderer::new(cfg.robot);
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);

    let n_test = (cfg.count as f64 * cfg.test_fraction).round() as usize;
    let mut order: Vec<usize> = (0..cfg.count).collect();
    order.shuffle(&mut rng);
    let mut split = vec![Split::Train; cfg.count];
    for &i in &order[..n_test] {
        split[i] = Split::Test;
    }
    let a = cfg.max_head_angle;
    let plans: Vec<Plan> = split
        .into_iter()
        .map(|split| {
            let yaw = if a > 0.0 { rng.gen_range(-a..=a) } else { 0.0 };
            let pitch = if a > 0.0 { rng.gen_range(-a..=a) } else { 0.0 };
            let var = Variation::random(&mut rng);
            let rng_seed: u64 = rng.gen();
            // From the frame's own seed: the fixed light's draws (and bytes) stay as they were.
            let mut lrng = ChaCha8Rng::seed_from_u64(rng_seed ^ 0x119E_7000);
            let var = match cfg.light.draw(split == Split::Train, &mut lrng) {
                Some(l) => var.lit(l),
                None => var,
            };
            // From the frame's own seed, so that the main draws do not depend on this share.
            let keep_clean = ChaCha8Rng::seed_from_u64(rng_seed ^ 0x5EED_C1EA).gen::<f64>()
                < cfg.unmarked_test_fraction;
            // Also from the frame's own seed: the other scene keeps the mirror dataset's draws.
            let seen = (cfg.scene == DatasetScene::Other).then(|| {
                let mut r = ChaCha8Rng::seed_from_u64(rng_seed ^ 0x07E4_0B07);
                if a > 0.0 { [r.gen_range(-a..=a), r.gen_range(-a..=a)] } else { [0.0; 2] }
            });
            Plan { yaw, pitch, var, split, marked: split == Split::Test && !keep_clean, rng_seed, seen }
        })
        .collect();

    let mut frames = Vec::with_capacity(cfg.count);
    let mut angles = String::new();
    for (i, p) in plans.iter().enumerate() {
        let file = format!("frames/{i:06}.png");
        let camera = [p.yaw, p.pitch];
        // The body in view: ours in the mirror, or the other robot's.
        let [sy, sp] = p.seen.unwrap_or(camera);
        let pose = BodyPose::head(sy, sp);
        let full = [0, 0, body::WIDTH, body::HEIGHT];
        let mut mark_record = None;
        let rendered = if p.marked {
            let mut mrng = ChaCha8Rng::seed_from_u64(p.rng_seed);
            // The mark is chosen on the face in view as its own mirror shows it (as episodes
            // do), then seen from our camera.
            let (mark, r) = render_marked(&renderer, &pose, &p.var, &mut mrng);
            let r = if p.seen.is_some() { renderer.render_seen(camera, &pose, Some(&mark), &p.var, full) } else { r };
            let px = r.mark.as_ref().expect("a marked render has mark pixels");
            let mask = format!("masks/{i:06}.png");
            written += write_png(&out.join(&mask), px.mask.as_raw(), body::WIDTH, body::HEIGHT, image::ExtendedColorType::L8)?;
            let ph = mark.point_head();
            // In the torso frame of the body that carries it.
            let pt = kin::head_to_torso(&ph, sy, sp);
            mark_record = Some(MarkRecord {
                shape: mark.kind.to_string(),
                colour: mark.colour.to_string(),
                rgb: mark.rgb,
                box_xyxy_inclusive: px.box_xyxy,
                pixels: px.pixels,
                mask,
                point_head_m: ph.coords.into(),
                point_torso_m: pt.coords.into(),
            });
            r
        } else {
            renderer.render_seen(camera, &pose, None, &p.var, full)
        };
        let rgb = cfg.camera.apply(&rendered.rgb, p.rng_seed ^ 0xCA3E_7A00);
        written += write_png(&out.join(&file), rgb.as_raw(), body::WIDTH, body::HEIGHT, image::ExtendedColorType::Rgb8)?;
        angles.push_str(&format!("{:.10},{:.10}\n", p.yaw, p.pitch));
        frames.push(FrameRecord {
            file,
            head_yaw: p.yaw,
            head_pitch: p.pitch,
            split: p.split,
            mark: mark_record,
            seen_head: p.seen,
        });
        progress(i + 1, written);
    }
    std::fs::write(out.join(layout::ANGLES_FILE), angles)?;
    let t = renderer.template();
    write_png(&out.join(layout::TEMPLATE_FILE), t.as_raw(), t.width(), t.height(), image::ExtendedColorType::L8)?;
    if cfg.reach_pairs > 0 {
        write_reach_pairs(out, cfg.reach_pairs, cfg.seed)?;
    }
    let index = DatasetIndex {
        robot: cfg.robot.name().to_string(),
        seed: cfg.seed,
        width: body::WIDTH,
        height: body::HEIGHT,
        template: layout::TEMPLATE_FILE.to_string(),
        frames,
        camera_controls: None,
        imperfections: (!cfg.camera.is_none()).then_some(cfg.camera),
    };
    let json = serde_json::to_vec_pretty(&index)?;
    std::fs::write(out.join(layout::INDEX_FILE), json)?;
    Ok(index)
}

/// Draws a random mark and renders it; redraws the colour while the mark is too faint, then
/// the place, so that every test mark is visible (at most a few dozen tries).
pub fn render_marked<R: Rng>(
    renderer: &Renderer,
    pose: &BodyPose,
    var: &Variation,
    rng: &mut R,
) -> (Mark, crate::render::Rendered) {
    let mut mark = Mark::random(rng);
    let mut best: Option<(f32, Mark, crate::render::Rendered)> = None;
    for attempt in 0..24u32 {
        if attempt > 0 {
            let kind = mark.kind;
            mark = if attempt.is_multiple_of(4) {
                Mark::random_of_kind(kind, rng).expect("known kind")
            } else {
                Mark::of_kind(kind, mark.centre_yz, rng).expect("known kind")
            };
        }
        let r = renderer.render(pose, Some(&mark), var);
        let c = r.mark.as_ref().map_or(0.0, |m| if m.pixels > 0 { m.contrast } else { 0.0 });
        if c >= MIN_MARK_CONTRAST {
            return (mark, r);
        }
        if best.as_ref().is_none_or(|b| c > b.0) {
            best = Some((c, mark.clone(), r));
        }
    }
    let (_, m, r) = best.expect("at least one attempt");
    (m, r)
}

/// A reach training pair: the mark's pixel at head (0, 0) and the IK posture that touches it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReachPair {
    /// The mark's pixel at head pose (0, 0).
    pub pixel: [f64; 2],
    /// The mark's point in the head frame, metres.
    pub point_head: [f64; 3],
    /// The reach joints' angles that put the fingertip on the point.
    pub joints: kin::Reach,
}

/// `n` reach pairs over the mark area, deterministic for `seed`.
pub fn reach_pairs(n: usize, seed: u64) -> Vec<ReachPair> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5EAC_4A11);
    let mut out = Vec::with_capacity(n);
    let mut tries = 0;
    while out.len() < n && tries < n * 10 + 100 {
        tries += 1;
        let y = rng.gen_range(body::FACE_Y[0]..=body::FACE_Y[1]);
        let z = rng.gen_range(body::FACE_Z[0]..=body::FACE_Z[1]);
        let Some(p) = body::face_point(y, z) else { continue };
        let Some(pixel) = body::project_head(&p, 0.0, 0.0) else { continue };
        if let Ok(joints) = kin::ik_touch(&p) {
            out.push(ReachPair { pixel, point_head: p.coords.into(), joints });
        }
    }
    out
}

/// Writes [`layout::REACH_CENTROIDS_FILE`] and [`layout::REACH_JOINTS_FILE`].
pub fn write_reach_pairs(out: &Path, n: usize, seed: u64) -> Result<usize> {
    let pairs = reach_pairs(n, seed);
    let mut c = String::new();
    let mut j = String::new();
    for p in &pairs {
        c.push_str(&format!("{},{}\n", p.pixel[0].round(), p.pixel[1].round()));
        let q = p.joints;
        j.push_str(&format!("{:.10},{:.10},{:.10},{:.10},{:.10}\n", q[0], q[1], q[2], q[3], q[4]));
    }
    std::fs::write(out.join(layout::REACH_CENTROIDS_FILE), c)?;
    std::fs::write(out.join(layout::REACH_JOINTS_FILE), j)?;
    Ok(pairs.len())
}

/// PNG with fast compression: the dataset is large and rewritten often.
/// Writes a PNG; returns its size in bytes.
fn write_png(path: &Path, data: &[u8], w: u32, h: u32, ct: image::ExtendedColorType) -> Result<u64> {
    let mut buf = Vec::with_capacity(data.len() / 2);
    PngEncoder::new_with_quality(&mut buf, CompressionType::Fast, FilterType::Sub)
        .write_image(data, w, h, ct)
        .with_context(|| format!("encoding {}", path.display()))?;
    let mut f = std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
    f.write_all(&buf).with_context(|| format!("writing {}", path.display()))?;
    Ok(buf.len() as u64)
}

#[cfg(test)]
mod tests;
