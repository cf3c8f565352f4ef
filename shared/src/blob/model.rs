//! A validated model blob, and the parser that makes one from bytes it does not trust.

use super::{
    MAGIC, VERSION, MAX_POOL, BLOCK, HEADER_LEN, MAX_FACE_H, MAX_FACE_W, MAX_LAYERS,
    MAX_ACTIVATION_LEN, MAX_TEMPLATE_PIXELS, REACH_FLOATS, FLAG_TEMPLATE, FLAG_SUBPIXEL,
    FLAG_REGION, FLAG_SELF_GATE, FLAG_POOL, FLAG_POSE, FLAG_SPREAD, FLAG_CHROMA, MAX_SPREAD_REF, CRC32,
};
use super::chroma::{self, Chroma};
use super::error::BlobError;
use super::settings::{
    Merge, Normalisation, Novelty, PoseGrid, PoseRegion, PoseStats, SelfGate, Sided,
};
use super::view::{
    Activation, CropMode, Layer, LayerKind, Reach, Shape, Template, U16Table, WeightOrder,
    WeightType,
};

/// A validated model blob.
#[derive(Clone, Debug, PartialEq)]
pub struct Model<'a> {
    /// Face crop height the model expects, pixels (`1..=MAX_FACE_H`).
    pub face_h: u16,
    /// Face crop width the model expects, pixels (`1..=MAX_FACE_W`).
    pub face_w: u16,
    /// Threshold, normalisation and blob settings.
    pub novelty: Novelty,
    /// The decoder, head angles in, predicted face out.
    pub layers: heapless::Vec<Layer<'a>, MAX_LAYERS>,
    /// Mean prediction error per pixel, Q8.8 grey levels, row-major.
    pub mu: U16Table<'a>,
    /// Its standard deviation per pixel, Q8.8 grey levels, row-major.
    pub sigma: U16Table<'a>,
    /// The reach network, mark centroid to joint angles.
    pub reach: Reach,
    /// Settings of their own near one head pose (flag bit 2).
    pub region: Option<PoseRegion>,
    /// The face template the host crops with (flag bit 0).
    pub template: Option<Template<'a>>,
    /// The self gate (flag bit 3); `None`: confirmed marks are reached at once, as the paper.
    pub self_gate: Option<SelfGate>,
    /// Error statistics per head-pose cell (flag bit 5); `None`: [`Model::mu`] and
    /// [`Model::sigma`] at every pose.
    pub pose: Option<PoseStats<'a>>,
    /// The face's colour (flag bit 7); `None`: a grey model.
    pub chroma: Option<Chroma<'a>>,
    /// The CRC-32 from the header: the model's identity.
    pub crc32: u32,
    /// Where the reach network's floats start.
    pub(super) reach_at: usize,
    /// Where the chroma section starts, or would.
    pub(super) chroma_at: usize,
    /// Where the self-gate section starts (its length depends on its layout).
    pub(super) gate_at: usize,
}

/// Bounds-checked little-endian reads; every failure is [`BlobError::Truncated`].
struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], BlobError> {
        let end = self.pos.checked_add(n).ok_or(BlobError::Truncated)?;
        let s = self.buf.get(self.pos..end).ok_or(BlobError::Truncated)?;
        self.pos = end;
        Ok(s)
    }
    /// Takes `n` bytes and skips padding to the next multiple of 4.
    fn take_padded(&mut self, n: usize) -> Result<&'a [u8], BlobError> {
        let s = self.take(n)?;
        let pad = (4 - n % 4) % 4;
        self.take(pad)?;
        Ok(s)
    }
    fn u8(&mut self) -> Result<u8, BlobError> {
        Ok(self.take(1)?[0])
    }
    fn i8(&mut self) -> Result<i8, BlobError> {
        Ok(self.u8()? as i8)
    }
    fn u16(&mut self) -> Result<u16, BlobError> {
        let b = self.take(2)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }
    fn u32(&mut self) -> Result<u32, BlobError> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn f32(&mut self) -> Result<f32, BlobError> {
        Ok(f32::from_bits(self.u32()?))
    }
}

fn checked_mul(a: usize, b: usize, e: BlobError) -> Result<usize, BlobError> {
    a.checked_mul(b).ok_or(e)
}

impl<'a> Model<'a> {
    /// Validates a blob and borrows its tables. Nothing in `bytes` is trusted.
    pub fn parse(bytes: &'a [u8]) -> Result<Model<'a>, BlobError> {
        Self::parse_inner(bytes, true)
    }

    /// [`Model::parse`] without the CRC pass, for a blob that `parse` accepted before and that
    /// has not changed since: the board re-borrows its running model for every frame, and the
    /// CRC of a large blob would cost more than the rest of the frame. Every other check runs.
    pub fn parse_trusted(bytes: &'a [u8]) -> Result<Model<'a>, BlobError> {
        Self::parse_inner(bytes, false)
    }

    fn parse_inner(bytes: &'a [u8], check_crc: bool) -> Result<Model<'a>, BlobError> {
        if bytes.len() < HEADER_LEN {
            return Err(BlobError::Truncated);
        }
        let mut r = Reader { buf: bytes, pos: 0 };
        if r.take(4)? != MAGIC {
            return Err(BlobError::BadMagic);
        }
        let version = r.u16()?;
        if !(1..=VERSION).contains(&version) {
            return Err(BlobError::UnsupportedVersion(version));
        }
        if r.u16()? as usize != HEADER_LEN {
            return Err(BlobError::BadHeader);
        }
        let total = r.u32()? as usize;
        if total > bytes.len() {
            return Err(BlobError::Truncated);
        }
        if total != bytes.len() {
            return Err(BlobError::LengthMismatch);
        }
        let crc = r.u32()?;
        if check_crc && CRC32.checksum(&bytes[16..]) != crc {
            return Err(BlobError::Crc);
        }
        let face_h = r.u16()?;
        let face_w = r.u16()?;
        if face_h == 0 || face_w == 0 || face_h as usize > MAX_FACE_H || face_w as usize > MAX_FACE_W
        {
            return Err(BlobError::FaceSize);
        }
        let n_layers = r.u16()? as usize;
        if n_layers == 0 || n_layers > MAX_LAYERS {
            return Err(BlobError::TooManyLayers);
        }
        let flags = r.u16()?;
        let v5 = FLAG_SELF_GATE | FLAG_POOL | FLAG_POSE;
        if flags & !(FLAG_TEMPLATE | FLAG_SUBPIXEL | FLAG_REGION | v5 | FLAG_SPREAD | FLAG_CHROMA) != 0
            || (flags & FLAG_SUBPIXEL != 0 && (version < 4 || flags & FLAG_TEMPLATE == 0))
            || (flags & FLAG_REGION != 0 && version < 4)
            || (flags & v5 != 0 && version < 5)
            || (version == 5 && flags & v5 == 0)
            || (flags & FLAG_SPREAD != 0 && version < 6)
            || (version == 6 && flags & FLAG_SPREAD == 0)
            || (flags & FLAG_CHROMA != 0) != (version >= 7)
        {
            return Err(BlobError::BadHeader);
        }
        let threshold = r.f32()?;
        let normalisation = match r.u8()? {
            0 => Normalisation::StdDev,
            1 => Normalisation::Variance,
            _ => return Err(BlobError::Novelty),
        };
        let sided = match r.u8()? {
            0 => Sided::One,
            1 => Sided::Two,
            _ => return Err(BlobError::Novelty),
        };
        let min_area = r.u16()?;
        let sigma_floor = r.f32()?;
        if !(threshold.is_finite() && threshold > 0.0)
            || min_area == 0
            || !(sigma_floor.is_finite() && sigma_floor >= 0.0)
        {
            return Err(BlobError::Novelty);
        }
        let merge_margin = r.u8()?;
        let pool = r.u8()?;
        let merge = Merge { margin: merge_margin, fragment: r.u16()? };
        if (flags & FLAG_POOL == 0 && pool != 0) || (version < 3 && merge != Merge::OFF) {
            return Err(BlobError::BadHeader);
        }
        if flags & FLAG_POOL != 0 && !(1..=MAX_POOL).contains(&pool) {
            return Err(BlobError::Novelty);
        }
        if !merge.is_valid(min_area) {
            return Err(BlobError::Novelty);
        }

        let mut layers = heapless::Vec::new();
        let mut prev = Shape { c: 2, h: 1, w: 1 };
        for i in 0..n_layers {
            let layer = parse_layer(&mut r, i as u8)?;
            if version < 2 && layer.order != WeightOrder::Torch {
                return Err(BlobError::BadLayer(i as u8));
            }
            if i == 0 {
                if layer.input.len() != 2 || layer.kind != LayerKind::Dense {
                    return Err(BlobError::ModelShape);
                }
            } else if layer.input != prev
                && !(layer.kind == LayerKind::Dense && layer.input.len() == prev.len())
            {
                return Err(BlobError::Chain(i as u8));
            }
            let last = i + 1 == n_layers;
            if !last && layer.output.len() > MAX_ACTIVATION_LEN {
                return Err(BlobError::ActivationTooLarge(i as u8));
            }
            prev = layer.output;
            // Cannot fail: n_layers <= MAX_LAYERS was checked.
            let _ = layers.push(layer);
        }
        if prev != (Shape { c: 1, h: face_h, w: face_w }) {
            return Err(BlobError::ModelShape);
        }

        let pixels = face_h as usize * face_w as usize;
        let mu = U16Table(r.take_padded(2 * pixels)?);
        let sigma = U16Table(r.take_padded(2 * pixels)?);

        let reach_at = r.pos;
        let mut floats = [0f32; REACH_FLOATS];
        for f in floats.iter_mut() {
            *f = r.f32()?;
        }
        let reach = Reach::from_floats(&floats);
        if !reach.is_valid() {
            return Err(BlobError::Reach);
        }
        let region = if flags & FLAG_REGION != 0 {
            let centre = [r.f32()?, r.f32()?];
            let (radius, threshold) = (r.f32()?, r.f32()?);
            let margin = r.u8()?;
            if r.u8()? != 0 {
                return Err(BlobError::BadHeader);
            }
            let merge = Merge { margin, fragment: r.u16()? };
            let region = PoseRegion { centre, radius, threshold, merge };
            if !region.is_valid(min_area) {
                return Err(BlobError::Novelty);
            }
            Some(region)
        } else {
            None
        };

        let template = if flags & FLAG_TEMPLATE != 0 {
            let h = r.u16()?;
            let w = r.u16()?;
            let n = h as usize * w as usize;
            if h == 0 || w == 0 || n > MAX_TEMPLATE_PIXELS {
                return Err(BlobError::Template);
            }
            let crop = if flags & FLAG_SUBPIXEL != 0 {
                CropMode::Subpixel
            } else {
                CropMode::Pixel
            };
            Some(Template { h, w, pixels: r.take_padded(n)?, crop })
        } else {
            None
        };
        let pose = if flags & FLAG_POSE != 0 {
            let bins = [r.u8()?, r.u8()?];
            if r.u16()? != 0 {
                return Err(BlobError::BadHeader);
            }
            let (yaw_lo, yaw_hi, pitch_lo, pitch_hi) = (r.f32()?, r.f32()?, r.f32()?, r.f32()?);
            let grid = PoseGrid { bins, lo: [yaw_lo, pitch_lo], hi: [yaw_hi, pitch_hi] };
            if !grid.is_valid() {
                return Err(BlobError::PoseStats);
            }
            let len = 2 * pixels;
            let stride = len + (4 - len % 4) % 4;
            // At most 2 x 16 tables of MAX_FACE_PIXELS: no overflow.
            let tables = r.take(2 * grid.len() * stride)?;
            Some(PoseStats { grid, tables, stride, len })
        } else {
            None
        };
        let spread_ref = if flags & FLAG_SPREAD != 0 {
            let s = r.f32()?;
            if !(0.0..=MAX_SPREAD_REF).contains(&s) {
                return Err(BlobError::Novelty);
            }
            Some(s)
        } else {
            None
        };
        let chroma_at = r.pos;
        let chroma = if flags & FLAG_CHROMA != 0 {
            let (threshold, spread_ref) = (r.f32()?, r.f32()?);
            if !chroma::valid_scalars(threshold, spread_ref) {
                return Err(BlobError::Chroma);
            }
            let cells = r.u8()? as usize;
            if r.take(3)? != [0; 3] {
                return Err(BlobError::BadHeader);
            }
            if cells != 1 && pose.as_ref().is_none_or(|p| p.grid.len() != cells) {
                return Err(BlobError::Chroma);
            }
            let n = chroma::blocks(face_h as usize, face_w as usize);
            let padded = n.div_ceil(4) * 4;
            // At most 16 cells of 3 tables of 1536 blocks: no overflow.
            let tables = r.take(3 * padded * cells)?;
            let c = Chroma { threshold, spread_ref, tables, n, cells };
            for k in 0..cells {
                let cell = c.cell(k).ok_or(BlobError::Truncated)?;
                if cell.tables().2.contains(&0) {
                    return Err(BlobError::Chroma);
                }
            }
            Some(c)
        } else {
            None
        };
        let gate_at = r.pos;
        let self_gate = if flags & FLAG_SELF_GATE != 0 {
            let (amplitude, gain, gain_tol, rest_tol) = (r.f32()?, r.f32()?, r.f32()?, r.f32()?);
            let (latency_ms, timeout_ms, min_frames) = (r.u16()?, r.u16()?, r.u8()?);
            let layout = r.u8()?;
            if r.take(2)? != [0; 2] {
                return Err(BlobError::BadHeader);
            }
            let (hold_tol, level_tol, line_tol, joint_tol) = match layout {
                0 => (rest_tol, rest_tol, None, None),
                1 => (r.f32()?, r.f32()?, None, None),
                2 => (r.f32()?, r.f32()?, Some(r.f32()?), None),
                3 => (r.f32()?, r.f32()?, Some(r.f32()?), Some(r.f32()?)),
                _ => return Err(BlobError::BadHeader),
            };
            let g = SelfGate { amplitude, gain, gain_tol, rest_tol, hold_tol, level_tol, line_tol, joint_tol, latency_ms, timeout_ms, min_frames };
            if !g.is_valid() {
                return Err(BlobError::SelfGate);
            }
            Some(g)
        } else {
            None
        };
        if r.pos != bytes.len() {
            return Err(BlobError::TrailingBytes);
        }
        Ok(Model {
            face_h,
            face_w,
            novelty: Novelty { threshold, normalisation, sided, min_area, sigma_floor, merge, pool, spread_ref },
            layers,
            mu,
            sigma,
            reach,
            region,
            template,
            self_gate,
            pose,
            chroma,
            crc32: crc,
            reach_at,
            chroma_at,
            gate_at,
        })
    }

    /// Pixels of a face crop, `face_h * face_w`.
    pub fn face_pixels(&self) -> usize {
        self.face_h as usize * self.face_w as usize
    }

    /// The (mu, sigma) tables for a face seen with the head at `head`, and which they are: 0
    /// for the header's tables (no pose statistics, or a non-finite pose), `1 + cell` for a
    /// cell's of [`Model::pose`].
    pub fn stats_at(&self, head: [f32; 2]) -> (U16Table<'a>, U16Table<'a>, u8) {
        if let Some(p) = &self.pose {
            if let Some((bin, (mu, sigma))) = p.grid.bin(head).and_then(|b| Some((b, p.tables(b)?))) {
                return (mu, sigma, 1 + bin as u8);
            }
        }
        (self.mu, self.sigma, 0)
    }

    /// The chroma tables for a frame seen with the head at `head`: its pose cell's when the
    /// section has one per cell, the first for a non-finite pose; `None` for a grey model.
    pub fn chroma_at(&self, head: [f32; 2]) -> Option<chroma::ChromaCell<'a>> {
        let c = self.chroma?;
        let k = match (&self.pose, c.cells()) {
            (Some(p), n) if n > 1 => p.grid.bin(head).unwrap_or(0),
            _ => 0,
        };
        c.cell(k)
    }

    /// Multiply-accumulates of one decoder inference.
    pub fn decoder_macs(&self) -> u64 {
        self.layers.iter().map(|l| l.macs()).sum()
    }
}

fn parse_layer<'a>(r: &mut Reader<'a>, i: u8) -> Result<Layer<'a>, BlobError> {
    let bad = BlobError::BadLayer(i);
    let shape_err = BlobError::LayerShape(i);
    let kind = match r.u8()? {
        0 => LayerKind::Dense,
        1 => LayerKind::ConvTranspose2d,
        2 => LayerKind::UpConv,
        3 => LayerKind::Crop,
        _ => return Err(bad),
    };
    let activation = match r.u8()? {
        0 => Activation::Identity,
        1 => Activation::Tanh,
        2 => Activation::Sigmoid,
        3 => Activation::Relu,
        _ => return Err(bad),
    };
    let weight_type = match r.u8()? {
        1 => WeightType::I8,
        2 => WeightType::I16,
        _ => return Err(bad),
    };
    let order = match r.u8()? {
        0 => WeightOrder::Torch,
        1 => WeightOrder::Blocked,
        _ => return Err(bad),
    };
    let input = Shape { c: r.u16()?, h: r.u16()?, w: r.u16()? };
    let output = Shape { c: r.u16()?, h: r.u16()?, w: r.u16()? };
    let kernel = r.u8()?;
    let stride = r.u8()?;
    let padding = r.u8()?;
    if r.u8()? != 0 {
        return Err(bad);
    }
    let crop_top = r.u16()?;
    let crop_left = r.u16()?;
    let w_shift = r.i8()?;
    let in_shift = r.i8()?;
    let out_shift = r.i8()?;
    if r.u8()? != 0 {
        return Err(bad);
    }
    // Shifts outside 0..=31 would make the fixed-point arithmetic overflow or lose everything.
    if !(0..=31).contains(&w_shift) || !(0..=31).contains(&in_shift) || !(0..=31).contains(&out_shift)
    {
        return Err(bad);
    }
    let weight_bytes = r.u32()? as usize;
    if input.is_empty() || output.is_empty() {
        return Err(shape_err);
    }
    if order == WeightOrder::Blocked && (kind != LayerKind::Dense || !input.len().is_multiple_of(BLOCK))
    {
        return Err(bad);
    }
    let (k, s, p) = (kernel as usize, stride as usize, padding as usize);
    let (weights, bias) = match kind {
        LayerKind::Dense => (
            checked_mul(input.len(), output.len(), shape_err)?,
            output.len(),
        ),
        LayerKind::ConvTranspose2d => {
            if input.c == 0 || k == 0 || s == 0 {
                return Err(shape_err);
            }
            // (in - 1) * s - 2p + k, without going negative.
            let want = |n: u16| ((n as usize - 1) * s + k).checked_sub(2 * p);
            if want(input.h) != Some(output.h as usize) || want(input.w) != Some(output.w as usize)
            {
                return Err(shape_err);
            }
            (input.c as usize * output.c as usize * k * k, output.c as usize)
        }
        LayerKind::UpConv => {
            if k == 0 || s == 0 {
                return Err(shape_err);
            }
            // in * s + 2p - k + 1.
            let want = |n: u16| (n as usize * s + 2 * p + 1).checked_sub(k);
            if want(input.h) != Some(output.h as usize) || want(input.w) != Some(output.w as usize)
            {
                return Err(shape_err);
            }
            (input.c as usize * output.c as usize * k * k, output.c as usize)
        }
        LayerKind::Crop => {
            if input.c != output.c
                || crop_top as usize + output.h as usize > input.h as usize
                || crop_left as usize + output.w as usize > input.w as usize
                || activation != Activation::Identity
            {
                return Err(shape_err);
            }
            (0, 0)
        }
    };
    if checked_mul(weights, weight_type.size(), shape_err)? != weight_bytes {
        return Err(shape_err);
    }
    let weights = r.take_padded(weight_bytes)?;
    let bias = r.take(4 * bias)?;
    Ok(Layer {
        kind,
        activation,
        weight_type,
        order,
        input,
        output,
        kernel,
        stride,
        padding,
        crop_top,
        crop_left,
        w_shift,
        in_shift,
        out_shift,
        weights,
        bias,
    })
}
