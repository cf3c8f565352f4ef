//! One face frame through every detection stage: decoder, photometric fit, saliency, blobs,
//! winner, reach.
//!
//! [`Workspace`] is the big state (activation buffers, threshold table, labeller; the mask lives
//! in the decoder's spare buffer). It has no heap and a `const` constructor, so a binary can put
//! it in a `static`. [`detect`] is the pure per-frame function the host tools and the board share.

use crate::blobs::merge;
use crate::blobs::{Blob, FaceLabeller, Summary};
use crate::chroma;
use crate::decoder::{DecodeError, Decoder};
use crate::floor;
use crate::light::{self, LightFit, Verdict};
use crate::reach;
use crate::room::Room;
use crate::saliency::{self, Settings, Thresholds};
use msr_shared::blob::{Model, Sided, MAX_FACE_H, REACH_OUT};

/// Why a frame was not processed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DetectError {
    /// The crop is not `face_h * face_w` bytes.
    CropSize,
    /// The chroma planes are not two of the model's chroma blocks.
    ChromaSize,
    /// The novelty settings are out of range.
    Settings,
    /// The decoder refused the model (see [`DecodeError`]).
    Decode(DecodeError),
}

impl core::fmt::Display for DetectError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            DetectError::CropSize => {
                f.write_str("face crop size differs from the model's face size")
            }
            DetectError::ChromaSize => {
                f.write_str("chroma planes' size differs from the model's chroma blocks")
            }
            DetectError::Settings => f.write_str("novelty settings out of range"),
            DetectError::Decode(e) => write!(f, "decoder: {e}"),
        }
    }
}

impl From<DecodeError> for DetectError {
    fn from(e: DecodeError) -> Self {
        DetectError::Decode(e)
    }
}

/// What one frame gave.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaceDetection {
    /// The winning component, in crop pixels.
    pub blob: Option<Blob>,
    /// Its centroid in full-frame pixels (crop offset + crop centroid), `[x, y]`.
    pub centroid: Option<[f32; 2]>,
    /// Reach targets for `REACH_JOINTS`, clamped to the limits.
    pub reach: Option<[f32; REACH_OUT]>,
    /// Reach angles that had to be clamped.
    pub reach_clamped: u32,
    /// Pixels that passed the saliency test.
    pub salient_pixels: u32,
    /// All components found, and whether the labeller overflowed.
    pub blobs: Summary,
    /// The frame's photometric fit and verdict: anything but [`Verdict::Face`] finds nothing.
    pub light: LightFit,
    /// What the frame's colour gave, for a model with chroma and a frame with its planes.
    pub chroma: Option<chroma::Frame>,
}

/// Scratch and caches for [`detect`]; about 55 KiB.
pub struct Workspace {
    /// The face predictor and its cached prediction.
    pub decoder: Decoder,
    /// The per-pixel threshold table, cached per model and setting.
    pub thresholds: Thresholds,
    /// The connected-component labeller.
    pub labeller: FaceLabeller,
    /// The head pose of the last [`decode`](Self::decode): its pose cell's statistics are
    /// the saliency's ([`Model::stats_at`]).
    head: [f32; 2],
    /// Salient pixels per row of the last mask, when its saliency counted them (the pooled
    /// one-sided test): the labeller skips the empty rows.
    row_counts: Option<[u16; MAX_FACE_H]>,
    /// The last frame's photometric fit, and its table `v(I)`.
    light: LightFit,
    lut: light::Lut,
    /// The last frame's spread and floor, Q8.8 ([`crate::floor`]).
    spread: [u16; 2],
    /// The last frame's colour ([`crate::chroma`]).
    chroma: Option<chroma::Frame>,
    /// Fit the light of each frame ([`light::fit`]; the default). Off: `v(I) = I << 8` and no
    /// frame refused, the error as the paper defines it (for comparisons).
    pub fit_light: bool,
    /// What the board has learnt of the room's light ([`crate::room`]); the threshold table
    /// takes it. [`Workspace::learn`] feeds it; a caller that never does keeps it at 0.
    pub room: Room,
    /// The room generation the cached prediction has added.
    room_applied: Option<u32>,
    /// The last [`decode`](Self::decode) ran the network.
    afresh: bool,
}

impl Default for Workspace {
    fn default() -> Self {
        Self::new()
    }
}

impl Workspace {
    /// Empty scratch; `const`, so it can live in a `static`.
    pub const fn new() -> Self {
        Workspace {
            decoder: Decoder::new(),
            thresholds: Thresholds::new(),
            labeller: FaceLabeller::new(),
            head: [f32::NAN; 2],
            row_counts: None,
            light: LightFit::IDENTITY,
            lut: light::Lut::IDENTITY,
            spread: [0; 2],
            chroma: None,
            fit_light: true,
            room: Room::new(),
            room_applied: None,
            afresh: false,
        }
    }

    /// Forgets every cache (call after a model change; [`detect`] also notices one by its CRC).
    pub fn invalidate(&mut self) {
        self.decoder.invalidate();
        self.thresholds.invalidate();
        self.row_counts = None;
    }

    /// Stage 1: the predicted face (cached per head pose), with what the board learnt of the
    /// room added ([`Decoder::predict_with`]: by the network's last layer, or [`Room::apply`];
    /// the network runs again when that changes).
    pub fn decode(&mut self, model: &Model, head: [f32; 2]) -> Result<&[u16], DecodeError> {
        self.head = head;
        self.row_counts = None;
        if self.room_applied != Some(self.room.generation()) {
            self.decoder.invalidate();
        }
        self.room_applied = Some(self.room.generation());
        let runs = self.decoder.runs();
        let made = self.decoder.predict_with(model, head, &self.room).map(|_| ());
        self.afresh = self.decoder.runs() != runs;
        made?;
        Ok(self.decoder.face().unwrap_or(&[]))
    }

    /// The last [`saliency`](Self::saliency)'s frame: its spread and the floor it took, Q8.8
    /// grey levels ([`crate::floor`]; 0 and 0 for a frame the fit refused, or for a model
    /// without a reference; a frame refused for its floor keeps them, to say why).
    pub fn spread(&self) -> [u16; 2] {
        self.spread
    }

    /// Whether the last [`decode`](Self::decode) ran the network (a new head pose, model or
    /// room) rather than taking the cached face: such a frame has paid for a prediction, so
    /// the board neither learns from it nor settles a batch on it ([`crate::room`], rules 1
    /// and 3).
    pub fn afresh(&self) -> bool {
        self.afresh
    }

    /// Stage 2: the photometric fit of `crop` to the last predicted face ([`light::fit`]), then
    /// the saliency mask of the fitted crop against it; returns the count of salient pixels. A
    /// frame the fit refuses ([`Workspace::light`]) gets an empty mask. Call
    /// [`decode`](Self::decode) first. The mask is [`mask`](Self::mask).
    pub fn saliency(
        &mut self,
        model: &Model,
        s: &Settings,
        crop: &[u8],
    ) -> Result<u32, DetectError> {
        if crop.len() != model.face_pixels() {
            return Err(DetectError::CropSize);
        }
        if !s.is_valid() {
            return Err(DetectError::Settings);
        }
        let (mu, _, _) = model.stats_at(self.head);
        let (face, mask) = self.decoder.face_and_scratch();
        let face = face.ok_or(DetectError::Decode(DecodeError::BadInput))?;
        if face.len() != crop.len() || mask.len() < crop.len() {
            return Err(DetectError::CropSize);
        }
        let (w, pool) = (model.face_w as usize, model.novelty.pool);
        self.row_counts = None;
        self.spread = [0; 2];
        self.chroma = None;
        if !self.fit_light {
            self.light = LightFit::IDENTITY;
            self.lut = light::Lut::IDENTITY;
        } else {
            self.light = light::fit(crop, face, w);
            if self.light.verdict == Verdict::Face {
                self.light.lut(&mut self.lut);
            }
        }
        // The frame's own floor ([`crate::floor`]), for a model that carries its reference; a
        // floor past its bound is not this face through a camera (rule 5).
        if let (Verdict::Face, Some(r)) = (self.light.verdict, floor::reference(model)) {
            let spread = floor::spread(crop, face, &self.lut, w, pool);
            self.spread = [spread, floor::floor(spread, r)];
            if self.spread[1] > floor::MAX_FLOOR {
                self.light.verdict = Verdict::NoFace;
            }
        }
        if self.light.verdict != Verdict::Face {
            mask[..crop.len()].fill(0);
            self.row_counts = Some([0; MAX_FACE_H]);
            return Ok(0);
        }
        let (lut, f) = (&self.lut, self.spread[1]);
        self.thresholds.prepare(model, s, self.head, f);
        let tn = self.thresholds.table();
        Ok(match (pool, s.sided) {
            (0, _) => saliency::saliency(crop, face, lut, mu, tn, s.sided, mask),
            (_, Sided::One) => {
                // The mask, then the ring of error rows behind it, in the decoder's spare buffer.
                let (mask, rest) = mask.split_at_mut(crop.len());
                let (_, ring, _) = bytemuck::pod_align_to_mut::<u8, i32>(rest);
                let mut rows = [0u16; MAX_FACE_H];
                // The decision stays the pooled mask's; its extent is the mark's own pixels.
                let n = saliency::pool::pooled_one_sided(crop, face, lut, tn, mask, ring, w, pool, &mut rows, true);
                self.row_counts = Some(rows);
                n
            }
            (_, Sided::Two) => saliency::pooled(crop, face, lut, mu, tn, s.sided, mask, w, pool),
        })
    }

    /// Stage 2b, after [`saliency`](Self::saliency) on the same `crop`: the blocks whose colour
    /// the face does not have ([`crate::chroma`]) join the mask; returns the pixels they add.
    /// Nothing for a model without chroma or a frame the fit refused.
    pub fn chroma(&mut self, model: &Model, crop: &[u8], planes: &[u8]) -> Result<u32, DetectError> {
        let Some(c) = model.chroma_at(self.head) else { return Ok(0) };
        let (h, w) = (model.face_h as usize, model.face_w as usize);
        if planes.len() != 2 * c.blocks() {
            return Err(DetectError::ChromaSize);
        }
        if crop.len() != h * w {
            return Err(DetectError::CropSize);
        }
        if self.light.verdict != Verdict::Face {
            return Ok(0);
        }
        let (_, scratch) = self.decoder.face_and_scratch();
        let (mask, rest) = scratch.split_at_mut(crop.len());
        // The errors in the scratch after the mask: 4 bytes a block, 6 KiB at most.
        let (_, e, _) = bytemuck::pod_align_to_mut::<u8, [i16; 2]>(rest);
        let Some(f) = chroma::errors(&c, crop, planes, h, w, e) else {
            return Err(DetectError::ChromaSize);
        };
        let rows = self.row_counts.as_mut().map(|r| &mut r[..]);
        let (f, added) = chroma::mark(&c, f, e, h, w, mask, rows);
        self.chroma = Some(f);
        Ok(added)
    }

    /// Online self-calibration ([`crate::room`], rules 2 and 3) from the last frame through
    /// [`saliency`](Self::saliency), `crop`, taken at `now_us`: the caller has checked rule 1
    /// (a face, no blob, no candidate, observing) and settled a complete batch first
    /// ([`crate::room::Room::settle`]; else this frame settles it instead of being learnt
    /// from). Returns true when the offsets changed (the next frame's prediction is made again).
    pub fn learn(&mut self, model: &Model, crop: &[u8], now_us: u64) -> bool {
        if self.light.verdict != Verdict::Face || crop.len() != model.face_pixels() {
            return false;
        }
        let (face, mask) = self.decoder.face_and_scratch();
        let Some(face) = face else { return false };
        self.room.learn(now_us, crop, face, &self.lut, mask, model.face_w as usize)
    }

    /// The photometric fit of the last [`saliency`](Self::saliency) call.
    pub fn light(&self) -> LightFit {
        self.light
    }

    /// The mask of the last [`saliency`](Self::saliency) call: 0 not salient, 1 salient,
    /// [`crate::extent::SPREAD`] salient through its pooling window only (not in the extent).
    pub fn mask(&mut self, pixels: usize) -> &[u8] {
        let m = self.decoder.scratch();
        let n = pixels.min(m.len());
        &m[..n]
    }

    /// Stage 3 and 4: components of the mask, and the winner among them (among the merged
    /// fragments when `s` merges them: [`crate::blobs::merge`]).
    pub fn blobs(&mut self, model: &Model, s: &Settings) -> (Option<Blob>, Summary) {
        let (w, h) = (model.face_w as usize, model.face_h as usize);
        let mask = self.decoder.scratch();
        let counts = self.row_counts.as_ref().map_or(&[][..], |c| &c[..]);
        merge::pick(&mut self.labeller, mask, w, h, counts, s.min_area, s.merge)
    }
}

/// The whole per-frame pipeline on one face crop (`face_h x face_w` grey bytes, row-major) at
/// `offset = [x, y]` in the camera frame, seen with the head at `head = [HeadYaw, HeadPitch]`
/// (radians, as the servos report them). `settings` are those in force; near the model's pose
/// region the region's apply ([`Settings::at`]).
pub fn detect(
    ws: &mut Workspace,
    model: &Model,
    settings: &Settings,
    crop: &[u8],
    offset: [u16; 2],
    head: [f32; 2],
) -> Result<FaceDetection, DetectError> {
    detect_colour(ws, model, settings, crop, None, offset, head)
}

/// [`detect`] with the frame's chroma planes (`Cb` then `Cr`, one byte a 2 x 2 block:
/// [`msr_shared::blob::chroma`]): a model with chroma also finds what only colour shows. A
/// model without chroma ignores them; `None` runs any model on grey alone.
pub fn detect_colour(
    ws: &mut Workspace,
    model: &Model,
    settings: &Settings,
    crop: &[u8],
    planes: Option<&[u8]>,
    offset: [u16; 2],
    head: [f32; 2],
) -> Result<FaceDetection, DetectError> {
    if crop.len() != model.face_pixels() {
        return Err(DetectError::CropSize);
    }
    let settings = settings.at(model, head);
    ws.decode(model, head)?;
    let mut salient_pixels = ws.saliency(model, &settings, crop)?;
    if let Some(p) = planes {
        salient_pixels += ws.chroma(model, crop, p)?;
    }
    let (blob, blobs) = ws.blobs(model, &settings);
    let centroid = blob.map(|b| {
        let c = b.centroid();
        [c[0] + offset[0] as f32, c[1] + offset[1] as f32]
    });
    let clamped = centroid.and_then(|c| reach::targets(&model.reach, c));
    Ok(FaceDetection {
        blob,
        centroid,
        reach: clamped.map(|(a, _)| a),
        reach_clamped: clamped.map_or(0, |(_, n)| n),
        salient_pixels,
        blobs,
        light: ws.light,
        chroma: ws.chroma,
    })
}

#[cfg(test)]
mod tests;
