//! Loading a dataset for training and evaluation: frames -> grey face crops, head angles, split and
//! mark ground truth.
//!
//! Two layouts are read:
//! - the sim layout (`dataset.json`, see `msr_sim::layout`), with exact mark masks;
//! - real recordings in the published layout (`manifest.json` as in `shared/data/nao-red-real`):
//!   every frame is a test frame, marks are given by their box (the published marks are pasted
//!   rectangles, so the box is the mask).
//!
//! Frames are cropped as they load (template matching on 2 threads, in the [`CropMode`] asked for)
//! and only the crops are kept.
pub mod crop;
pub mod npy;
use crate::data::crop::{chroma_planes, crop_face_with, load_colour, load_grey, CropBox, CropMode, Face};
use msr_sim::imperfect::Imperfections;
use anyhow::{anyhow, bail, ensure, Context, Result};
use image::GrayImage;
use msr_shared::joints::Joint;
use msr_sim::layout::{DatasetIndex, Split, INDEX_FILE};
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// Robot names a sim-layout index may give: `msr dataset --robot`'s, and `msr record`'s.
pub const ROBOT_NAMES: [&str; 3] = ["red", "skin", "recorded"];

/// What an index says, checked before any frame is read, as `msr dataset` and `msr record`
/// write it: a known robot, every frame once, inside the dataset folder, at head angles the Nao
/// can take.
fn check_index(root: &Path, robot: &str, pending: &[Pending], layout: Layout) -> Result<()> {
    if layout == Layout::Sim && !ROBOT_NAMES.contains(&robot) {
        bail!(
            "dataset {} says robot {robot:?}: a sim dataset's robot is red or skin, a recording's is recorded",
            root.display()
        );
    }
    let mut seen = std::collections::HashMap::new();
    for (i, p) in pending.iter().enumerate() {
        let rel = p.file.strip_prefix(root).unwrap_or(&p.file);
        if !rel.components().all(|c| matches!(c, std::path::Component::Normal(_))) {
            bail!("dataset {}: frame {} lies outside the dataset folder", root.display(), rel.display());
        }
        if let Some(j) = seen.insert(rel.to_path_buf(), i) {
            bail!(
                "dataset {}: frame {} is listed twice (entries {} and {}): each frame counts once",
                root.display(),
                rel.display(),
                j + 1,
                i + 1
            );
        }
        for (joint, a) in [(Joint::HeadYaw, p.head[0]), (Joint::HeadPitch, p.head[1])] {
            joint.validate(a as f32).map_err(|e| {
                anyhow!("dataset {}: frame {}: head {e} (the Nao's joint range)", root.display(), rel.display())
            })?;
        }
    }
    Ok(())
}

/// The published layout's index file.
pub const MANIFEST_FILE: &str = "manifest.json";

/// The ground truth of one mark.
#[derive(Clone, Debug, PartialEq)]
pub struct MarkTruth {
    /// The mark's colour name, e.g. "green".
    pub colour: String,
    /// e.g. "rectangle"; "pasted" for the published real frames.
    pub shape: String,
    /// Inclusive box in full-frame pixels: [x0, y0, x1, y1].
    pub box_xyxy: [u32; 4],
    /// Mark pixels in the whole frame.
    pub pixels: u32,
    /// Mark pixels in face coordinates, row-major `face_h x face_w`.
    pub face_mask: Vec<bool>,
    /// True when the mask came from a mask file, false when it was filled from the box.
    pub exact_mask: bool,
}

impl MarkTruth {
    /// Mark pixels that fall inside the face crop.
    pub fn pixels_in_face(&self) -> usize {
        self.face_mask.iter().filter(|&&m| m).count()
    }

    /// Whether a full-frame point lies in the mark's box (inclusive).
    pub fn box_contains(&self, x: f32, y: f32) -> bool {
        let [x0, y0, x1, y1] = self.box_xyxy.map(|v| v as f32);
        x >= x0 && x <= x1 && y >= y0 && y <= y1
    }
}

/// One frame, cropped.
#[derive(Clone, Debug, PartialEq)]
pub struct Sample {
    /// The frame file (dataset folder joined).
    pub file: PathBuf,
    /// [HeadYaw, HeadPitch], radians.
    pub head: [f32; 2],
    /// Whether the frame is for training or for testing.
    pub split: Split,
    /// The face crop and where it was cut.
    pub face: Face,
    /// The mark on the face, `None` for a clean frame.
    pub mark: Option<MarkTruth>,
}

impl Sample {
    /// The crop as grey/255, row-major.
    pub fn face_unit(&self) -> Vec<f32> {
        self.face.unit()
    }
    /// Where the face was cut from the frame, full-frame pixels.
    pub fn crop(&self) -> CropBox {
        self.face.crop
    }
}

/// Which layout a dataset was read from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// The sim's `dataset.json`, with mark masks (sim datasets and recordings).
    Sim,
    /// The published `manifest.json` of real frames, marks given by their box.
    Published,
}

/// A loaded dataset.
#[derive(Clone, Debug)]
pub struct Dataset {
    /// The dataset folder, which the index's paths are relative to.
    pub root: PathBuf,
    /// Which index file it was read from.
    pub layout: Layout,
    /// "red"/"skin" for sim data, free text for recordings.
    pub robot: String,
    /// The grey face template the crops were made with.
    pub template: GrayImage,
    /// How the crops were made.
    pub crop: CropMode,
    /// Size (width, height) of every frame, pixels.
    pub frame_size: (u32, u32),
    /// The frames read, cropped, in index order.
    pub samples: Vec<Sample>,
    /// Frames that show another robot, not the mirror image (`msr dataset --scene other`).
    pub other_robot_frames: usize,
}

impl Dataset {
    /// Loads every frame of the dataset at `path` (a folder holding `dataset.json` or
    /// `manifest.json`, or one of those files).
    pub fn load(path: &Path, crop: CropMode) -> Result<Dataset> {
        Self::load_split(path, None, crop)
    }

    /// Loads only the frames of one split (`None`: all).
    pub fn load_split(path: &Path, only: Option<Split>, crop: CropMode) -> Result<Dataset> {
        Self::load_through(path, only, crop, &Imperfections::NONE)
    }

    /// [`Dataset::load_split`], each colour frame taken through `camera` before it is turned to
    /// grey and cropped (the frame's place in the index numbers its noise draws).
    pub fn load_through(path: &Path, only: Option<Split>, crop: CropMode, camera: &Imperfections) -> Result<Dataset> {
        let (root, index) = locate(path)?;
        let other_robot_frames = match &index {
            Index::Sim(ix) => ix.frames.iter().filter(|f| f.seen_head.is_some()).count(),
            Index::Published(_) => 0,
        };
        let (layout, pending, robot, template_file, size) = match index {
            Index::Sim(ix) => {
                let (robot, tpl, size) =
                    (ix.robot.clone(), ix.template.clone(), (ix.width, ix.height));
                (Layout::Sim, sim_frames(&root, ix, None)?, robot, tpl, size)
            }
            Index::Published(m) => {
                let tpl = m.face_crop.template.clone();
                let size = (m.camera.width, m.camera.height);
                (
                    Layout::Published,
                    published_frames(&root, m, None)?,
                    "published".into(),
                    tpl,
                    size,
                )
            }
        };
        // The whole index is checked, whichever split is read.
        check_index(&root, &robot, &pending, layout)?;
        let pending: Vec<(u64, Pending)> = pending
            .into_iter()
            .enumerate()
            .filter(|(_, p)| only.is_none_or(|s| s == p.split))
            .map(|(i, p)| (i as u64, p))
            .collect();
        let template = load_grey(&root.join(&template_file))
            .with_context(|| format!("dataset {}: face template", root.display()))?;
        let samples = parallel_map(&pending, |(i, p)| p.load(&template, crop, size, camera, *i))?;
        Ok(Dataset {
            root,
            layout,
            robot,
            template,
            crop,
            frame_size: size,
            samples,
            other_robot_frames,
        })
    }

    /// Face size (height, width).
    pub fn face_size(&self) -> (usize, usize) {
        (
            self.template.height() as usize,
            self.template.width() as usize,
        )
    }

    /// The samples of split `s`, in order.
    pub fn split(&self, s: Split) -> impl Iterator<Item = &Sample> {
        self.samples.iter().filter(move |x| x.split == s)
    }

    /// Head angles and unit faces of one split, in order (what training takes).
    pub fn arrays(&self, s: Split) -> (Vec<[f32; 2]>, Vec<Vec<f32>>) {
        self.split(s).map(|x| (x.head, x.face_unit())).unzip()
    }
}

enum Index {
    Sim(DatasetIndex),
    Published(Manifest),
}

/// Finds the index file and parses it.
fn locate(path: &Path) -> Result<(PathBuf, Index)> {
    let (root, file) = if path.is_dir() {
        if path.join(INDEX_FILE).is_file() {
            (path.to_path_buf(), path.join(INDEX_FILE))
        } else if path.join(MANIFEST_FILE).is_file() {
            (path.to_path_buf(), path.join(MANIFEST_FILE))
        } else {
            bail!(
                "{} holds neither {INDEX_FILE} nor {MANIFEST_FILE}",
                path.display()
            );
        }
    } else if path.is_file() {
        let parent = path.parent().unwrap_or(Path::new(".")).to_path_buf();
        (parent, path.to_path_buf())
    } else {
        bail!("dataset {} does not exist", path.display());
    };
    let text = std::fs::read_to_string(&file)
        .with_context(|| format!("cannot read {}", file.display()))?;
    let is_manifest = file.file_name().is_some_and(|n| n == MANIFEST_FILE)
        || serde_json::from_str::<serde_json::Value>(&text)
            .map(|v| v.get("images").is_some())
            .unwrap_or(false);
    let index = if is_manifest {
        Index::Published(
            serde_json::from_str(&text)
                .with_context(|| format!("{} is not a valid manifest", file.display()))?,
        )
    } else {
        Index::Sim(
            serde_json::from_str(&text)
                .with_context(|| format!("{} is not a valid {INDEX_FILE}", file.display()))?,
        )
    };
    Ok((root, index))
}

/// What the published `manifest.json` says about frames (other sections are read by `import`).
#[derive(Deserialize, Debug)]
pub struct Manifest {
    /// The camera's frame size.
    pub camera: Camera,
    /// How faces are cropped: the template.
    pub face_crop: FaceCrop,
    /// The frames, each with its head angles and mark.
    pub images: Vec<ManifestImage>,
}

/// The manifest's `camera` section: the size of every frame.
#[derive(Deserialize, Debug)]
pub struct Camera {
    /// Frame width, pixels.
    pub width: u32,
    /// Frame height, pixels.
    pub height: u32,
}

/// The manifest's `face_crop` section.
#[derive(Deserialize, Debug)]
pub struct FaceCrop {
    /// The face template's file, relative to the dataset folder.
    pub template: String,
}

/// One frame of the manifest.
#[derive(Deserialize, Debug)]
pub struct ManifestImage {
    /// The frame's PNG file, relative to the dataset folder.
    pub file: String,
    /// HeadYaw when the frame was taken, radians.
    pub head_yaw: f64,
    /// HeadPitch when the frame was taken, radians.
    pub head_pitch: f64,
    /// The mark pasted on the frame, `None` for a clean frame.
    pub mark: Option<ManifestMark>,
}

/// A mark of the manifest: a pasted rectangle, so its box is its mask.
#[derive(Deserialize, Debug)]
pub struct ManifestMark {
    /// The mark's colour name, e.g. "green".
    pub colour: String,
    /// Box `[x0, y0, x1, y1]`, inclusive, full-frame pixels.
    pub box_xyxy_inclusive: [u32; 4],
    /// Mark pixels in the frame.
    pub pixels: u32,
}

/// A frame to read, with what the index says about it.
struct Pending {
    file: PathBuf,
    head: [f64; 2],
    split: Split,
    mark: Option<PendingMark>,
}

struct PendingMark {
    colour: String,
    shape: String,
    box_xyxy: [u32; 4],
    pixels: u32,
    /// None: fill the box.
    mask: Option<PathBuf>,
}

fn sim_frames(root: &Path, ix: DatasetIndex, only: Option<Split>) -> Result<Vec<Pending>> {
    Ok(ix
        .frames
        .into_iter()
        .filter(|f| only.is_none_or(|s| s == f.split))
        .map(|f| Pending {
            file: root.join(&f.file),
            head: [f.head_yaw, f.head_pitch],
            split: f.split,
            mark: f.mark.map(|m| PendingMark {
                colour: m.colour,
                shape: m.shape,
                box_xyxy: m.box_xyxy_inclusive,
                pixels: m.pixels,
                mask: Some(root.join(&m.mask)),
            }),
        })
        .collect())
}

fn published_frames(root: &Path, m: Manifest, only: Option<Split>) -> Result<Vec<Pending>> {
    // The published frames are held-out test frames (the training frames were not published).
    if only == Some(Split::Train) {
        return Ok(Vec::new());
    }
    Ok(m.images
        .into_iter()
        .map(|f| Pending {
            file: root.join(&f.file),
            head: [f.head_yaw, f.head_pitch],
            split: Split::Test,
            mark: f.mark.map(|k| PendingMark {
                colour: k.colour,
                shape: "pasted".into(),
                box_xyxy: k.box_xyxy_inclusive,
                pixels: k.pixels,
                mask: None,
            }),
        })
        .collect())
}

impl Pending {
    fn load(&self, template: &GrayImage, crop: CropMode, (fw, fh): (u32, u32), camera: &Imperfections, index: u64) -> Result<Sample> {
        let name = self.file.display();
        ensure!(
            self.head.iter().all(|a| a.is_finite()),
            "frame {name}: head angles {:?} are not finite",
            self.head
        );
        let (frame, colour) = load_colour(&self.file, camera, index)?;
        ensure!(
            frame.dimensions() == (fw, fh),
            "frame {name} is {}x{}, the dataset says {fw}x{fh}",
            frame.width(),
            frame.height()
        );
        let mut face = crop_face_with(&frame, template, crop).with_context(|| format!("frame {name}"))?;
        if let Some(rgb) = &colour {
            face.chroma = chroma_planes(rgb, &face);
        }
        let mark = match &self.mark {
            None => None,
            Some(m) => Some(
                m.load(face.crop, (fw, fh))
                    .with_context(|| format!("frame {name}"))?,
            ),
        };
        Ok(Sample {
            file: self.file.clone(),
            head: self.head.map(|a| a as f32),
            split: self.split,
            face,
            mark,
        })
    }
}

impl PendingMark {
    fn load(&self, crop: CropBox, (fw, fh): (u32, u32)) -> Result<MarkTruth> {
        let [x0, y0, x1, y1] = self.box_xyxy;
        ensure!(
            x0 <= x1 && y0 <= y1 && x1 < fw && y1 < fh,
            "mark box {:?} is not inside the {fw}x{fh} frame",
            self.box_xyxy
        );
        let inside = |x: u32, y: u32| x >= x0 && x <= x1 && y >= y0 && y <= y1;
        let (face_mask, exact) = match &self.mask {
            None => (face_mask(crop, inside), false),
            Some(path) => {
                let mask = image::open(path)
                    .with_context(|| format!("cannot read mark mask {}", path.display()))?
                    .to_luma8();
                ensure!(
                    mask.dimensions() == (fw, fh),
                    "mark mask {} is {}x{}, the frame is {fw}x{fh}",
                    path.display(),
                    mask.width(),
                    mask.height()
                );
                (face_mask(crop, |x, y| mask.get_pixel(x, y)[0] != 0), true)
            }
        };
        Ok(MarkTruth {
            colour: self.colour.clone(),
            shape: self.shape.clone(),
            box_xyxy: self.box_xyxy,
            pixels: self.pixels,
            face_mask,
            exact_mask: exact,
        })
    }
}

fn face_mask(crop: CropBox, is_mark: impl Fn(u32, u32) -> bool) -> Vec<bool> {
    (crop.y..crop.y + crop.height)
        .flat_map(|y| (crop.x..crop.x + crop.width).map(move |x| (x, y)))
        .map(|(x, y)| is_mark(x, y))
        .collect()
}

/// Maps `f` over `items` on all cores, in order; the first error wins.
pub fn parallel_map<T: Sync, U: Send>(
    items: &[T],
    f: impl Fn(&T) -> Result<U> + Sync,
) -> Result<Vec<U>> {
    let threads = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1);
    let chunk = items.len().div_ceil(threads).max(1);
    let results: Vec<Result<Vec<U>>> = std::thread::scope(|s| {
        let handles: Vec<_> = items
            .chunks(chunk)
            .map(|c| s.spawn(|| c.iter().map(&f).collect::<Result<Vec<U>>>()))
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().map_err(|_| anyhow!("a loader thread panicked"))?)
            .collect()
    });
    let mut out = Vec::with_capacity(items.len());
    for r in results {
        out.extend(r?);
    }
    Ok(out)
}
