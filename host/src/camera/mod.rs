//! Camera frames, from wherever they come: a folder of PNGs, the sim's renderer, a Y4M stream
//! (standard input, so that any camera tool can feed `msr`), or a V4L2 camera. Every source is a
//! [`FrameSource`]; [`open`] makes one from a [`SourceConfig`] and wraps it so that every frame
//! comes out grey at the size the model's template was made for ([`Frames`]).
pub mod hold;
pub mod v4l2;
pub mod y4m;

use crate::data::crop;
use anyhow::{bail, Context, Result};
use image::GrayImage;
use msr_sim::Robot;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// One grey camera frame and a name to report it by.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Where the frame came from: its file's path, or the source's name and frame number.
    pub name: String,
    /// The frame's pixels, 8-bit grey.
    pub grey: GrayImage,
}

/// A camera. `next_frame` gives `Ok(None)` at the end of a finite source (a folder, a stream
/// that closed between frames) and an error when a frame cannot be had (a stream cut mid-frame,
/// a camera that stopped delivering).
pub trait FrameSource {
    /// The next frame, `Ok(None)` at the end of the source.
    fn next_frame(&mut self) -> Result<Option<Frame>>;
    /// The head now stands at (yaw, pitch), radians. Only a rendered camera cares: a real one
    /// sees the head move by itself.
    fn head_moved(&mut self, _head: [f64; 2]) {}
    /// Drops frames read ahead and not yet taken, so that the next one is shot after this call
    /// (a live source buffers).
    fn discard_buffered(&mut self) {}
    /// The camera controls held (V4L2 values by [`hold::Ctl::name`]), for a camera that holds
    /// them; `None` for any other source.
    fn camera_controls(&self) -> Option<BTreeMap<String, i32>> {
        None
    }
}

/// What a V4L2 camera does with its automatic exposure, gain and white balance.
#[derive(Clone, Debug, PartialEq)]
pub enum Hold {
    /// Leaves them as they are.
    Off,
    /// Lets them run for `frames` frames, then switches them to manual ([`hold::plan`]) at the
    /// values they reached, or at `values` (a recording's `camera_controls`).
    Settle {
        /// Frames the automatics run for before the hold.
        frames: u32,
        /// Values to hold, by control name; `None`: the values the automatics reached.
        values: Option<BTreeMap<String, i32>>,
    },
}

/// Frames the automatics run for before the camera is held: about 1 s at 30 fps.
pub const SETTLE_FRAMES: u32 = 30;

impl Default for Hold {
    fn default() -> Hold {
        Hold::Settle { frames: SETTLE_FRAMES, values: None }
    }
}

/// Where frames come from.
#[derive(Clone, Debug, PartialEq)]
pub enum SourceConfig {
    /// PNG files of a folder, in name order.
    Folder(PathBuf),
    /// The sim's renderer for `robot`: `count` frames (`None`: for ever) at the head pose last
    /// given with [`FrameSource::head_moved`] (home at first), each with fresh camera noise; a
    /// random mark from frame `mark_from` on (`None`: never); lit as `light` plans, the frames
    /// 100 ms apart; taken through `camera`'s imperfections (its motion blur scaled by the
    /// head's speed between frames).
    Sim {
        /// The robot drawn.
        robot: Robot,
        /// Frames to give before the end; `None`: for ever.
        count: Option<usize>,
        /// Seed of the mark, the camera noise and the light's draws.
        seed: u64,
        /// The first frame (from 0) that shows the mark; `None`: no mark.
        mark_from: Option<usize>,
        /// How the light changes over the frames.
        light: msr_sim::light::LightPlan,
        /// The camera's imperfections (exposure, white balance, noise, blur, JPEG) the frames
        /// are taken through.
        camera: msr_sim::imperfect::Imperfections,
    },
    /// A YUV4MPEG2 stream on standard input.
    Y4mStdin,
    /// A V4L2 camera, e.g. `/dev/video0` (Linux), held still as `hold` says.
    Camera {
        /// The device node, e.g. `/dev/video0`.
        dev: PathBuf,
        /// What is done with the camera's automatic exposure, gain and white balance.
        hold: Hold,
    },
}

impl SourceConfig {
    /// `--frames PATH`: `-` is standard input (Y4M), anything else a folder.
    pub fn frames_arg(p: &Path) -> SourceConfig {
        if p.as_os_str() == "-" {
            SourceConfig::Y4mStdin
        } else {
            SourceConfig::Folder(p.to_path_buf())
        }
    }
}

/// How frames are delivered.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SourceOptions {
    /// Frame size the model's template was cut from; frames of another size with the same aspect
    /// ratio are scaled to it.
    pub size: [u32; 2],
    /// Longest wait for the next frame of a live source (a stream, a camera).
    pub timeout: Duration,
    /// Frame rate to ask a camera for (0: its own).
    pub fps: f64,
}

impl Default for SourceOptions {
    fn default() -> SourceOptions {
        SourceOptions {
            size: [msr_sim::body::WIDTH, msr_sim::body::HEIGHT],
            timeout: Duration::from_secs(5),
            fps: 0.0,
        }
    }
}

/// Opens a source.
pub fn open(cfg: &SourceConfig, opts: &SourceOptions) -> Result<Frames> {
    let inner: Box<dyn FrameSource> = match cfg {
        SourceConfig::Folder(dir) => Box::new(FolderSource::open(dir)?),
        SourceConfig::Sim { robot, count, seed, mark_from, light, camera } => {
            Box::new(SimSource::new(*robot, *count, *seed, *mark_from).with_light(*light).with_camera(*camera))
        }
        SourceConfig::Y4mStdin => {
            Box::new(y4m::Y4mSource::spawn(std::io::stdin(), "stdin", opts.timeout))
        }
        SourceConfig::Camera { dev, hold } => open_camera(dev, hold, opts)?,
    };
    Ok(Frames { inner, size: opts.size, scaled: 0 })
}

#[cfg(target_os = "linux")]
fn open_camera(dev: &Path, hold: &Hold, opts: &SourceOptions) -> Result<Box<dyn FrameSource>> {
    Ok(Box::new(v4l2::V4lSource::open(dev, opts.size, opts.fps, opts.timeout, hold)?))
}

#[cfg(not(target_os = "linux"))]
fn open_camera(dev: &Path, _hold: &Hold, opts: &SourceOptions) -> Result<Box<dyn FrameSource>> {
    let [w, h] = opts.size;
    bail!(
        "--camera {} needs Linux (V4L2); elsewhere stream the camera through ffmpeg: ffmpeg -i \
         CAMERA -f yuv4mpegpipe -pix_fmt gray -s {w}x{h} - | msr ... --frames -",
        dev.display()
    )
}

/// A source whose frames all come out at one size.
pub struct Frames {
    inner: Box<dyn FrameSource>,
    size: [u32; 2],
    /// Frames that were scaled.
    pub scaled: u64,
}

impl Frames {
    /// `inner`'s frames, each scaled to `size` (width, height) pixels by [`fit`].
    pub fn new(inner: Box<dyn FrameSource>, size: [u32; 2]) -> Frames {
        Frames { inner, size, scaled: 0 }
    }

    /// The source's next frame at the model's size, `Ok(None)` at its end; a frame that cannot
    /// be brought to that size is an error.
    pub fn next_frame(&mut self) -> Result<Option<Frame>> {
        let Some(mut f) = self.inner.next_frame()? else { return Ok(None) };
        if f.grey.dimensions() != (self.size[0], self.size[1]) {
            f.grey = fit(&f.grey, self.size).with_context(|| format!("frame {}", f.name))?;
            self.scaled += 1;
        }
        Ok(Some(f))
    }

    /// Tells the source the head now stands at (yaw, pitch), radians ([`FrameSource::head_moved`]).
    pub fn head_moved(&mut self, head: [f64; 2]) {
        self.inner.head_moved(head);
    }

    /// Drops the frames the source read ahead ([`FrameSource::discard_buffered`]).
    pub fn discard_buffered(&mut self) {
        self.inner.discard_buffered();
    }

    /// The camera controls the source holds ([`FrameSource::camera_controls`]).
    pub fn camera_controls(&self) -> Option<BTreeMap<String, i32>> {
        self.inner.camera_controls()
    }
}

/// `img` at `size`, the one rule for every path that takes camera frames (`msr run`, `msr record`,
/// `msr detect`): a frame of that size as it is, a larger one of the same aspect ratio scaled
/// down. A smaller frame is refused: scaling up invents the detail the decoder compares, and
/// every pixel it blurs is a "mark". Another aspect ratio is refused: stretching would change
/// the face's shape, and the template would no longer match it.
pub fn fit(img: &GrayImage, size: [u32; 2]) -> Result<GrayImage> {
    let (w, h) = img.dimensions();
    let [tw, th] = size;
    if w == 0 || h == 0 || tw == 0 || th == 0 {
        bail!("an empty frame ({w}x{h}) or frame size ({tw}x{th})");
    }
    if (w, h) == (tw, th) {
        return Ok(img.clone());
    }
    if w < tw || h < th {
        bail!(
            "the frame is {w}x{h}, smaller than the {tw}x{th} the model's template was cut from: \
             scaling it up would invent the face's detail; give frames of {tw}x{th} or larger"
        );
    }
    let ratio = (w as f64 / h as f64) / (tw as f64 / th as f64);
    if (ratio - 1.0).abs() > 0.01 {
        bail!(
            "the frame is {w}x{h}, another aspect ratio than the model's {tw}x{th}: crop it to \
             {tw}:{th} first (ffmpeg: -vf crop=...,scale={tw}:{th})"
        );
    }
    Ok(image::imageops::resize(img, tw, th, image::imageops::FilterType::Triangle))
}

/// The PNG files of a folder, read one at a time in name order.
pub struct FolderSource {
    files: std::vec::IntoIter<PathBuf>,
}

impl FolderSource {
    /// The PNG files (any case of `.png`) of `dir`; a folder without one is an error.
    pub fn open(dir: &Path) -> Result<FolderSource> {
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
            .with_context(|| format!("reading frame folder {}", dir.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")))
            .collect();
        files.sort();
        if files.is_empty() {
            bail!("no PNG frames in {}", dir.display());
        }
        Ok(FolderSource { files: files.into_iter() })
    }
}

impl FrameSource for FolderSource {
    fn next_frame(&mut self) -> Result<Option<Frame>> {
        let Some(p) = self.files.next() else { return Ok(None) };
        Ok(Some(Frame { name: p.display().to_string(), grey: crop::load_grey(&p)? }))
    }
}

/// The sim's camera: the robot in the mirror at the current head pose.
pub struct SimSource {
    renderer: msr_sim::render::Renderer,
    rng: rand_chacha::ChaCha8Rng,
    pose: msr_sim::body::BodyPose,
    mark: Option<msr_sim::marks::Mark>,
    mark_from: usize,
    count: Option<usize>,
    next: usize,
    light: msr_sim::light::LightSchedule,
    camera: msr_sim::imperfect::Imperfections,
    /// The head pose of the last frame, for the motion blur.
    last_head: Option<[f64; 2]>,
}

/// Simulated time between two frames of the sim source, for its light.
const SIM_FRAME_US: u64 = 100_000;

impl SimSource {
    /// This source lit as `plan` says over its frames (600 frames for an endless one).
    pub fn with_light(mut self, plan: msr_sim::light::LightPlan) -> SimSource {
        use rand::{Rng, SeedableRng};
        let frames = self.count.unwrap_or(600).max(1) as u64;
        // Drawn from the source's seed, apart from its noise.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(self.rng.clone().gen::<u64>() ^ 0x119E_7002);
        self.light = msr_sim::light::LightSchedule::new(plan, frames * SIM_FRAME_US, &mut rng);
        self
    }

    /// This source's frames through `camera`'s imperfections.
    pub fn with_camera(mut self, camera: msr_sim::imperfect::Imperfections) -> SimSource {
        self.camera = camera;
        self
    }

    /// `robot` at home under a fixed light, `count` frames (`None`: for ever), its draws from
    /// `seed`, the mark shown from frame `mark_from` on (`None`: never).
    pub fn new(robot: Robot, count: Option<usize>, seed: u64, mark_from: Option<usize>) -> SimSource {
        use rand::SeedableRng;
        let renderer = msr_sim::render::Renderer::new(robot);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let pose = msr_sim::body::BodyPose::head(0.0, 0.0);
        // The mark is drawn first (at home) whether or not it is shown, so that a seed gives the
        // same frames with and without a mark.
        let (mark, _) = msr_sim::dataset::render_marked(
            &renderer,
            &pose,
            &msr_sim::render::Variation::CLEAN,
            &mut rng,
        );
        SimSource {
            renderer,
            rng,
            pose,
            mark: mark_from.map(|_| mark),
            mark_from: mark_from.unwrap_or(usize::MAX),
            count,
            next: 0,
            light: msr_sim::light::LightSchedule::new(msr_sim::light::LightPlan::Fixed, 1, &mut rand_chacha::ChaCha8Rng::seed_from_u64(0)),
            camera: msr_sim::imperfect::Imperfections::NONE,
            last_head: None,
        }
    }
}

impl FrameSource for SimSource {
    fn next_frame(&mut self) -> Result<Option<Frame>> {
        let i = self.next;
        if self.count.is_some_and(|n| i >= n) {
            return Ok(None);
        }
        self.next += 1;
        let m = self.mark.as_ref().filter(|_| i >= self.mark_from);
        let light = self.light.at(i as u64 * SIM_FRAME_US);
        let var = msr_sim::render::Variation::random(&mut self.rng).lit(light);
        let r = self.renderer.render(&self.pose, m, &var);
        let head = [self.pose.head_yaw, self.pose.head_pitch];
        let dt = SIM_FRAME_US as f64 * 1e-6;
        let speed = self.last_head.map_or([0.0; 2], |h| [(head[0] - h[0]) / dt, (head[1] - h[1]) / dt]);
        self.last_head = Some(head);
        let rgb = self.camera.moving(speed).apply(&r.rgb, i as u64);
        self.light.observed(&rgb);
        let name = format!(
            "sim-{i:03}{}",
            m.map_or(String::new(), |m| format!(" ({} {})", m.colour, m.kind))
        );
        Ok(Some(Frame { name, grey: crop::to_grey(&image::DynamicImage::ImageRgb8(rgb)) }))
    }

    fn head_moved(&mut self, head: [f64; 2]) {
        self.pose.head_yaw = head[0];
        self.pose.head_pitch = head[1];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_frame_of_the_model_size_is_kept_and_others_are_scaled_or_refused() {
        let img = GrayImage::from_fn(640, 480, |x, _| image::Luma([(x / 2) as u8]));
        let out = fit(&img, [320, 240]).unwrap();
        assert_eq!(out.dimensions(), (320, 240));
        // A horizontal ramp halves: pixel 100 covers source pixels 200..202, grey 100.
        assert!((out.get_pixel(100, 50).0[0] as i32 - 100).abs() <= 1);
        let wide = GrayImage::new(640, 360);
        let e = fit(&wide, [320, 240]).unwrap_err().to_string();
        assert!(e.contains("640x360") && e.contains("aspect"), "{e}");
        // Smaller frames are never scaled up, whatever their aspect ratio.
        for (w, h) in [(40, 30), (319, 239), (160, 120), (320, 200)] {
            let e = fit(&GrayImage::new(w, h), [320, 240]).unwrap_err().to_string();
            assert!(e.contains(&format!("{w}x{h}")) && e.contains("smaller"), "{e}");
        }
    }

    #[test]
    fn the_sim_source_renders_the_pose_it_is_given() {
        let mut a = SimSource::new(Robot::Red, Some(2), 3, None);
        let mut b = SimSource::new(Robot::Red, Some(2), 3, None);
        let fa = a.next_frame().unwrap().unwrap();
        b.head_moved([0.05, 0.0]);
        let fb = b.next_frame().unwrap().unwrap();
        assert_eq!(fa.grey.dimensions(), (320, 240));
        assert_ne!(fa.grey, fb.grey, "the head turned");
        assert!(a.next_frame().unwrap().is_some());
        assert!(a.next_frame().unwrap().is_none(), "count 2");
    }

    #[test]
    fn a_folder_without_frames_is_a_clear_error() {
        let d = tempfile::tempdir().unwrap();
        let e = FolderSource::open(d.path()).err().unwrap().to_string();
        assert!(e.contains("no PNG frames"), "{e}");
    }
}
