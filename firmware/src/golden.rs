//! Golden vectors: a fixed set of frames through the whole pipeline, reduced to one digest.
//!
//! The frames are made from the model itself (its predicted face at a few head poses, plus
//! deterministic noise and square marks), so any blob works and nothing has to be shipped.
//! Every intermediate result that matters goes into a CRC-32: the predicted face, the
//! photometric fit, the frame's spread and floor, the mask, the winning blob, the centroid and reach bits. Four frames are
//! under another exposure and one is black, so that the fit and its verdict are compared too. Run it on the host and on the board with the
//! same blob: equal digests mean bit-identical pipelines. A model with chroma gets each frame's
//! chroma planes too (its own mean colour with noise, some frames a patch of another hue at the
//! face's grey), and the colour stage's results go into the digest.

use crate::pipeline::{detect_colour, DetectError, Workspace};
use msr_shared::blob::chroma;
use crate::saliency::Settings;
use msr_shared::blob::{Model, CRC32};

/// Frames in the set.
pub const FRAMES: u32 = 16;

/// What the golden run gave.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GoldenReport {
    /// Frames run (always [`FRAMES`]).
    pub frames: u32,
    /// Frames whose winner was found.
    pub detections: u32,
    /// CRC-32 over every frame's results.
    pub digest: u32,
}

struct XorShift(u32);

impl XorShift {
    fn next(&mut self) -> u32 {
        let mut x = self.0;
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        self.0 = x;
        x
    }
}

/// The head pose of golden frame `i`: a grid inside +-5 degrees.
pub fn head_pose(i: u32) -> [f32; 2] {
    let step = 0.0175f32; // about one degree
    [
        ((i * 7) % 11) as f32 * step - 5.0 * step,
        ((i * 5) % 9) as f32 * step - 4.0 * step,
    ]
}

/// Scratch [`run`] needs for a model: its face, and its chroma planes when it has chroma.
pub fn scratch_len(model: &Model) -> usize {
    let (h, w) = (model.face_h as usize, model.face_w as usize);
    h * w + if model.chroma.is_some() { 2 * chroma::blocks(h, w) } else { 0 }
}

/// Runs the golden frames. `crop` is scratch for one face and its planes ([`scratch_len`]).
pub fn run(
    ws: &mut Workspace,
    model: &Model,
    crop: &mut [u8],
) -> Result<GoldenReport, DetectError> {
    let (h, w) = (model.face_h as usize, model.face_w as usize);
    let n = h * w;
    let (crop, planes) = crop.get_mut(..scratch_len(model)).ok_or(DetectError::CropSize)?.split_at_mut(n);
    let settings = Settings::of(model);
    let mut digest = CRC32.digest();
    let mut detections = 0;
    for i in 0..FRAMES {
        let head = head_pose(i);
        let face = ws.decoder.predict_uncached(model, head)?;
        for v in face {
            digest.update(&v.to_le_bytes());
        }
        let mut rng = XorShift(0x9E37_79B9 ^ (i + 1).wrapping_mul(0x85EB_CA6B));
        for (c, &p) in crop.iter_mut().zip(face) {
            let noise = (rng.next() % 7) as i32 - 3;
            *c = (((p as i32 + 128) >> 8) + noise).clamp(0, 255) as u8;
        }
        // Odd frames carry a square mark of a random grey somewhere on the face.
        if i % 2 == 1 {
            let side = 7.min(h).min(w);
            let y0 = rng.next() as usize % (h - side + 1);
            let x0 = rng.next() as usize % (w - side + 1);
            let grey = (rng.next() % 256) as u8;
            for y in y0..y0 + side {
                crop[y * w + x0..y * w + x0 + side].fill(grey);
            }
        }
        // The light: frames 2, 6, 10 and 14 under another exposure and an offset (the
        // photometric fit takes them back), the last one black (no face).
        if i % 4 == 2 {
            let (gain, off) = (192 + (i as i32) * 6, (i as i32) - 8);
            for c in crop.iter_mut() {
                *c = ((*c as i32 * gain) / 256 + off).clamp(0, 255) as u8;
            }
        }
        if i == FRAMES - 1 {
            crop.fill(0);
        }
        let planes = match model.chroma_at(head) {
            Some(c) => {
                colour(&c, crop, planes, h, w, i, &mut rng);
                Some(&planes[..])
            }
            None => None,
        };
        let offset = [(i * 3) as u16, (i * 2) as u16];
        let det = detect_colour(ws, model, &settings, crop, planes, offset, head)?;
        if let Some(f) = det.chroma {
            for v in [f.shift[0] as u32 | (f.shift[1] as u32) << 16, f.gain[0] as u32 | (f.gain[1] as u32) << 16, f.median_q as u32, f.widen, f.blocks as u32] {
                digest.update(&v.to_le_bytes());
            }
        }
        for &m in ws.mask(n) {
            digest.update(&[m]);
        }
        if let Some(b) = det.blob {
            detections += 1;
            for v in [
                b.area as u64,
                b.x0 as u64,
                b.y0 as u64,
                b.x1 as u64,
                b.y1 as u64,
                b.sum_x,
                b.sum_y,
                b.first as u64,
            ] {
                digest.update(&v.to_le_bytes());
            }
        }
        for c in det
            .centroid
            .iter()
            .flatten()
            .chain(det.reach.iter().flatten())
        {
            digest.update(&c.to_bits().to_le_bytes());
        }
        let l = det.light;
        for v in [
            det.salient_pixels,
            det.blobs.components,
            det.blobs.overflow as u32,
            l.gain as u32,
            l.offset as u32,
            l.samples as u32 | (l.inliers as u32) << 16,
            l.correlation_milli as u32,
            l.verdict as u32,
            ws.spread()[0] as u32 | (ws.spread()[1] as u32) << 16,
        ] {
            digest.update(&v.to_le_bytes());
        }
    }
    Ok(GoldenReport {
        frames: FRAMES,
        detections,
        digest: digest.finalize(),
    })
}

/// Chroma planes for golden frame `i`: each block's `Cb`, `Cr` near the model's mean ratio at
/// the crop's grey, with noise; frames 0, 4, 8, 12 (no grey mark) a block patch of another hue
/// (the grey kept).
fn colour(c: &msr_shared::blob::ChromaCell, crop: &[u8], planes: &mut [u8], h: usize, w: usize, i: u32, rng: &mut XorShift) {
    let (bh, bw) = (h.div_ceil(2), w.div_ceil(2));
    let n = bh * bw;
    let patch = (i % 4 == 0).then(|| (rng.next() as usize % bh.saturating_sub(3).max(1), rng.next() as usize % bw.saturating_sub(3).max(1)));
    for by in 0..bh {
        for bx in 0..bw {
            let b = by * bw + bx;
            let (sum, px) = chroma::block_grey(crop, h, w, b);
            let (sum, px) = (sum as i32, px as i32);
            let (mu, _) = c.at(b).unwrap_or(([0, 0], 1));
            let inside = patch.is_some_and(|(py, pxx)| (py..py + 3).contains(&by) && (pxx..pxx + 3).contains(&bx));
            for (k, m) in mu.iter().enumerate() {
                // The inverse of the normalisation, rounded down, with noise of +-1.
                let base = 128 + (*m as i32 * (sum + chroma::DARK * px)) / (chroma::SCALE * px.max(1));
                let v = if inside { 128 + if k == 0 { -60 } else { 70 } } else { base + (rng.next() % 3) as i32 - 1 };
                planes[k * n + b] = v.clamp(0, 255) as u8;
            }
        }
    }
}

/// What [`room`] gave: its cost (from the caller's counter) and the offsets' digest.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RoomReport {
    /// Counter units (instructions on the board) per frame learnt from (its samples).
    pub learn: u64,
    /// Per update of every offset ([`crate::room::Room::settle`], on the frame after a
    /// batch's last).
    pub update: u64,
    /// Adding the offsets to one predicted face (a prediction with them less one without).
    pub apply: u64,
    /// CRC-32 of the offsets at the end (i16 little-endian), then of the face predicted with
    /// them (u16 little-endian): the host and the board compare it.
    pub digest: u32,
}

/// Online self-calibration ([`crate::room`]) on a fixed sequence: 32 frames of the face at
/// [`head_pose`]`(0)`, 2 grey levels brighter on its left half than predicted, with noise and
/// a mark on every fourth, each through saliency and then learnt from (a second apart); then
/// a prediction made with the offsets and one without. `counter` reads a clock (instructions
/// on the board; the host may return 0). The room is reset first and left as learnt.
pub fn room(
    ws: &mut Workspace,
    model: &Model,
    crop: &mut [u8],
    mut counter: impl FnMut() -> u64,
) -> Result<RoomReport, DetectError> {
    let (h, w) = (model.face_h as usize, model.face_w as usize);
    let crop = crop.get_mut(..h * w).ok_or(DetectError::CropSize)?;
    let settings = Settings::of(model).at(model, head_pose(0));
    ws.room.reset();
    ws.room.freeze(false);
    let mut r = RoomReport::default();
    let mut rng = XorShift(0x2545_F491);
    for i in 0..32u64 {
        let face = ws.decode(model, head_pose(0))?;
        for (k, (c, &p)) in crop.iter_mut().zip(face).enumerate() {
            let shade = if k % w < w / 2 { 2 } else { 0 };
            let noise = (rng.next() % 7) as i32 - 3;
            *c = (((p as i32 + 128) >> 8) + shade + noise).clamp(0, 255) as u8;
        }
        if i % 4 == 3 {
            let side = 7.min(h).min(w);
            for y in 0..side {
                crop[y * w..y * w + side].fill(255);
            }
        }
        ws.saliency(model, &settings, crop)?;
        let t0 = counter();
        ws.learn(model, crop, i * 1_000_000);
        r.learn += counter().wrapping_sub(t0) / 32;
        // The board's next frame, not learnt from: the update after a batch's last.
        if ws.room.pending() {
            let t0 = counter();
            ws.room.settle();
            r.update += counter().wrapping_sub(t0) / 4;
        }
    }
    // Rule 4's cost: a new prediction with the offsets less one without (the board adds them
    // as the network's last layer stores the face where it can, else in a pass of their own).
    let t0 = counter();
    ws.decoder.predict_uncached(model, head_pose(0))?;
    let plain = counter().wrapping_sub(t0);
    let t0 = counter();
    let face = ws.decoder.predict_uncached_with(model, head_pose(0), &ws.room)?;
    r.apply = counter().wrapping_sub(t0).saturating_sub(plain);
    let mut digest = CRC32.digest();
    for o in ws.room.offsets() {
        digest.update(&o.to_le_bytes());
    }
    for v in face {
        digest.update(&v.to_le_bytes());
    }
    r.digest = digest.finalize();
    Ok(r)
}

