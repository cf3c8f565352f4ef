//! The blob writer (std only): models built on the host, written in the layout the parser reads.
use super::{
    BLOCK, CRC32, FLAG_CHROMA, FLAG_POOL, FLAG_POSE, FLAG_REGION, FLAG_SELF_GATE, FLAG_SPREAD, FLAG_SUBPIXEL,
    FLAG_TEMPLATE, HEADER_LEN, MAGIC, MAX_POOL, REACH_FLOATS, REACH_HIDDEN, REACH_IN, REACH_OUT,
};
use super::chroma::ChromaSpec;
use super::error::BlobError;
use super::model::Model;
use super::settings::{Normalisation, Novelty, PoseGrid, PoseRegion, SelfGate, Sided};
use super::view::{Activation, CropMode, LayerKind, Reach, Shape};

/// Weights of a layer being written.
#[derive(Clone, Debug, PartialEq)]
pub enum Weights {
    /// `i8` weights.
    I8(Vec<i8>),
    /// `i16` weights.
    I16(Vec<i16>),
}

/// A layer to write; fields as in [`Layer`](super::view::Layer).
#[derive(Clone, Debug, PartialEq)]
pub struct LayerSpec {
    /// As [`Layer::kind`](super::view::Layer::kind).
    pub kind: LayerKind,
    /// As [`Layer::activation`](super::view::Layer::activation).
    pub activation: Activation,
    /// As [`Layer::input`](super::view::Layer::input).
    pub input: Shape,
    /// As [`Layer::output`](super::view::Layer::output).
    pub output: Shape,
    /// As [`Layer::kernel`](super::view::Layer::kernel).
    pub kernel: u8,
    /// As [`Layer::stride`](super::view::Layer::stride).
    pub stride: u8,
    /// As [`Layer::padding`](super::view::Layer::padding).
    pub padding: u8,
    /// As [`Layer::crop_top`](super::view::Layer::crop_top).
    pub crop_top: u16,
    /// As [`Layer::crop_left`](super::view::Layer::crop_left).
    pub crop_left: u16,
    /// As [`Layer::w_shift`](super::view::Layer::w_shift).
    pub w_shift: i8,
    /// As [`Layer::in_shift`](super::view::Layer::in_shift).
    pub in_shift: i8,
    /// As [`Layer::out_shift`](super::view::Layer::out_shift).
    pub out_shift: i8,
    /// In PyTorch order; the writer chooses the stored order.
    pub weights: Weights,
    /// One per output element (Dense) or output channel (convolutions), in the accumulator's scale.
    pub bias: Vec<i32>,
}

/// Everything that goes into a blob.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelSpec {
    /// Face height, pixels.
    pub face_h: u16,
    /// Face width, pixels.
    pub face_w: u16,
    /// As [`Model::novelty`].
    pub novelty: Novelty,
    /// The decoder layers, first (head angles in) to last (face out).
    pub layers: Vec<LayerSpec>,
    /// Mean prediction error per pixel, Q8.8 grey levels, row-major.
    pub mu: Vec<u16>,
    /// Its standard deviation per pixel, Q8.8 grey levels, row-major.
    pub sigma: Vec<u16>,
    /// As [`Model::reach`].
    pub reach: Reach,
    /// Novelty settings of their own near one head pose.
    pub region: Option<PoseRegion>,
    /// (h, w, grey pixels).
    pub template: Option<(u16, u16, Vec<u8>)>,
    /// How the host crops with the template; [`CropMode::Subpixel`] needs one.
    pub crop: CropMode,
    /// Error statistics per head-pose cell: the grid and each cell's (mu, sigma), Q8.8.
    pub pose: Option<(PoseGrid, Vec<(Vec<u16>, Vec<u16>)>)>,
}

fn pad(out: &mut Vec<u8>) {
    while !out.len().is_multiple_of(4) {
        out.push(0);
    }
}

impl ModelSpec {
    /// Serialises and then checks the result with [`Model::parse`], so a blob that this
    /// returns is one the board accepts.
    pub fn to_bytes(&self) -> Result<Vec<u8>, BlobError> {
        let blocked: Vec<bool> = (0..self.layers.len()).map(|i| self.blocked(i)).collect();
        let subpixel = self.crop == CropMode::Subpixel;
        if subpixel && self.template.is_none() {
            return Err(BlobError::Template);
        }
        if self.novelty.pool > MAX_POOL {
            return Err(BlobError::Novelty);
        }
        if self.novelty.spread_ref.is_some_and(|s| !(0.0..=super::MAX_SPREAD_REF).contains(&s)) {
            return Err(BlobError::Novelty);
        }
        let version: u16 = if self.novelty.spread_ref.is_some() {
            6
        } else if self.novelty.pool > 0 || self.pose.is_some() {
            5
        } else if subpixel || self.region.is_some() {
            4
        } else if self.novelty.merge.is_on() {
            3
        } else if blocked.contains(&true) {
            2
        } else {
            1
        };
        let mut o = Vec::new();
        o.extend_from_slice(&MAGIC);
        o.extend_from_slice(&version.to_le_bytes());
        o.extend_from_slice(&(HEADER_LEN as u16).to_le_bytes());
        o.extend_from_slice(&[0; 8]); // total_len, crc32: filled below
        o.extend_from_slice(&self.face_h.to_le_bytes());
        o.extend_from_slice(&self.face_w.to_le_bytes());
        o.extend_from_slice(&(self.layers.len() as u16).to_le_bytes());
        let mut flags = if self.template.is_some() { FLAG_TEMPLATE } else { 0 };
        if subpixel {
            flags |= FLAG_SUBPIXEL;
        }
        if self.region.is_some() {
            flags |= FLAG_REGION;
        }
        if self.novelty.pool > 0 {
            flags |= FLAG_POOL;
        }
        if self.pose.is_some() {
            flags |= FLAG_POSE;
        }
        if self.novelty.spread_ref.is_some() {
            flags |= FLAG_SPREAD;
        }
        o.extend_from_slice(&flags.to_le_bytes());
        let n = &self.novelty;
        o.extend_from_slice(&n.threshold.to_le_bytes());
        o.push(match n.normalisation {
            Normalisation::StdDev => 0,
            Normalisation::Variance => 1,
        });
        o.push(match n.sided {
            Sided::One => 0,
            Sided::Two => 1,
        });
        o.extend_from_slice(&n.min_area.to_le_bytes());
        o.extend_from_slice(&n.sigma_floor.to_le_bytes());
        o.push(n.merge.margin);
        o.push(n.pool);
        o.extend_from_slice(&n.merge.fragment.to_le_bytes());
        debug_assert_eq!(o.len(), HEADER_LEN);

        for (l, &blocked) in self.layers.iter().zip(&blocked) {
            o.push(match l.kind {
                LayerKind::Dense => 0,
                LayerKind::ConvTranspose2d => 1,
                LayerKind::UpConv => 2,
                LayerKind::Crop => 3,
            });
            o.push(match l.activation {
                Activation::Identity => 0,
                Activation::Tanh => 1,
                Activation::Sigmoid => 2,
                Activation::Relu => 3,
            });
            o.push(match l.weights {
                Weights::I8(_) => 1,
                Weights::I16(_) => 2,
            });
            o.push(blocked as u8);
            for v in [l.input.c, l.input.h, l.input.w, l.output.c, l.output.h, l.output.w] {
                o.extend_from_slice(&v.to_le_bytes());
            }
            o.extend_from_slice(&[l.kernel, l.stride, l.padding, 0]);
            o.extend_from_slice(&l.crop_top.to_le_bytes());
            o.extend_from_slice(&l.crop_left.to_le_bytes());
            o.extend_from_slice(&[l.w_shift as u8, l.in_shift as u8, l.out_shift as u8, 0]);
            let w: Vec<u8> = match &l.weights {
                Weights::I8(v) => v.iter().map(|&x| x as u8).collect(),
                Weights::I16(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            };
            let w = if blocked { block(l, &w) } else { w };
            o.extend_from_slice(&(w.len() as u32).to_le_bytes());
            o.extend_from_slice(&w);
            pad(&mut o);
            let bias: Vec<i32> = if blocked {
                let (c_n, hw) = (l.output.c as usize, l.output.h as usize * l.output.w as usize);
                (0..l.bias.len()).map(|j| l.bias[(j % c_n) * hw + j / c_n]).collect()
            } else {
                l.bias.clone()
            };
            for b in &bias {
                o.extend_from_slice(&b.to_le_bytes());
            }
        }
        for table in [&self.mu, &self.sigma] {
            for v in table.iter() {
                o.extend_from_slice(&v.to_le_bytes());
            }
            pad(&mut o);
        }
        for f in self.reach.to_floats() {
            o.extend_from_slice(&f.to_le_bytes());
        }
        if let Some(g) = &self.region {
            for f in [g.centre[0], g.centre[1], g.radius, g.threshold] {
                o.extend_from_slice(&f.to_le_bytes());
            }
            o.extend_from_slice(&[g.merge.margin, 0]);
            o.extend_from_slice(&g.merge.fragment.to_le_bytes());
        }
        if let Some((h, w, px)) = &self.template {
            o.extend_from_slice(&h.to_le_bytes());
            o.extend_from_slice(&w.to_le_bytes());
            o.extend_from_slice(px);
            pad(&mut o);
        }
        if let Some((g, cells)) = &self.pose {
            let pixels = self.face_h as usize * self.face_w as usize;
            if cells.len() != g.len()
                || cells.iter().any(|(m, s)| m.len() != pixels || s.len() != pixels)
            {
                return Err(BlobError::PoseStats);
            }
            o.extend_from_slice(&[g.bins[0], g.bins[1], 0, 0]);
            for f in [g.lo[0], g.hi[0], g.lo[1], g.hi[1]] {
                o.extend_from_slice(&f.to_le_bytes());
            }
            for table in cells.iter().flat_map(|(m, s)| [m, s]) {
                for v in table.iter() {
                    o.extend_from_slice(&v.to_le_bytes());
                }
                pad(&mut o);
            }
        }
        if let Some(s) = self.novelty.spread_ref {
            o.extend_from_slice(&s.to_le_bytes());
        }
        seal(o)
    }
}

/// The blob with its self-gate section replaced by `gate` (`None` removes it). A blob that
/// keeps no gate is written at the version its other sections need, so removing the gate
/// gives back the bytes the writer made before it was added.
pub fn set_self_gate(bytes: &[u8], gate: Option<SelfGate>) -> Result<Vec<u8>, BlobError> {
    let m = Model::parse(bytes)?;
    let mut o = bytes.to_vec();
    let flags = u16::from_le_bytes([o[22], o[23]]);
    if m.self_gate.is_some() {
        o.truncate(m.gate_at);
    }
    let mut flags = flags & !FLAG_SELF_GATE;
    if let Some(g) = gate {
        if !g.is_valid() {
            return Err(BlobError::SelfGate);
        }
        for f in [g.amplitude, g.gain, g.gain_tol, g.rest_tol] {
            o.extend_from_slice(&f.to_le_bytes());
        }
        o.extend_from_slice(&g.latency_ms.to_le_bytes());
        o.extend_from_slice(&g.timeout_ms.to_le_bytes());
        let layout = match (g.line_tol, g.joint_tol) {
            (None, _) => 1,
            (Some(_), None) => 2,
            (Some(_), Some(_)) => 3,
        };
        o.extend_from_slice(&[g.min_frames, layout, 0, 0]);
        for f in [g.hold_tol, g.level_tol].into_iter().chain(g.line_tol).chain(g.joint_tol) {
            o.extend_from_slice(&f.to_le_bytes());
        }
        flags |= FLAG_SELF_GATE;
    }
    let version = version_of(flags, &m, &o);
    o[4..6].copy_from_slice(&version.to_le_bytes());
    o[22..24].copy_from_slice(&flags.to_le_bytes());
    seal(o)
}

/// The version a blob with these `flags` is written at: the oldest that has every section
/// (`m` and the header bytes `o` for the older distinctions), so taking a section off gives
/// back the bytes the writer made before it was added.
fn version_of(flags: u16, m: &Model, o: &[u8]) -> u16 {
    let merge = u16::from_le_bytes([o[36], 0]) != 0;
    let blocked = m.layers.iter().any(|l| !l.torch_order());
    if flags & FLAG_CHROMA != 0 {
        7
    } else if flags & FLAG_SPREAD != 0 {
        6
    } else if flags & (FLAG_POOL | FLAG_POSE | FLAG_SELF_GATE) != 0 {
        5
    } else if flags & (FLAG_SUBPIXEL | FLAG_REGION) != 0 {
        4
    } else if merge {
        3
    } else if blocked {
        2
    } else {
        1
    }
}

/// The blob with its reach network replaced by `reach` (every other byte kept, the CRC made
/// again): a reach the robot taught itself goes into the model it was taught beside.
pub fn set_reach(bytes: &[u8], reach: &Reach) -> Result<Vec<u8>, BlobError> {
    let m = Model::parse(bytes)?;
    if !reach.is_valid() {
        return Err(BlobError::Reach);
    }
    let mut o = bytes.to_vec();
    for (i, f) in reach.to_floats().iter().enumerate() {
        o[m.reach_at + 4 * i..m.reach_at + 4 * i + 4].copy_from_slice(&f.to_le_bytes());
    }
    seal(o)
}

/// The blob with its chroma section replaced by `chroma` (`None` removes it; a grey model).
/// The self gate, which comes after it, is kept.
pub fn set_chroma(bytes: &[u8], chroma: Option<&ChromaSpec>) -> Result<Vec<u8>, BlobError> {
    let m = Model::parse(bytes)?;
    let mut o = bytes[..m.chroma_at].to_vec();
    let mut flags = u16::from_le_bytes([o[22], o[23]]) & !FLAG_CHROMA;
    if let Some(c) = chroma {
        let grid = m.pose.as_ref().map_or(0, |p| p.grid.len());
        if !c.is_valid(m.face_h as usize, m.face_w as usize, grid) {
            return Err(BlobError::Chroma);
        }
        o.extend_from_slice(&c.threshold.to_le_bytes());
        o.extend_from_slice(&c.spread_ref.to_le_bytes());
        o.extend_from_slice(&[c.cells.len() as u8, 0, 0, 0]);
        for (mu, spread) in &c.cells {
            o.extend(mu.iter().map(|p| p[0] as u8));
            pad(&mut o);
            o.extend(mu.iter().map(|p| p[1] as u8));
            pad(&mut o);
            o.extend_from_slice(spread);
            pad(&mut o);
        }
        flags |= FLAG_CHROMA;
    }
    o.extend_from_slice(&bytes[m.gate_at..]);
    let version = version_of(flags, &m, &o);
    o[4..6].copy_from_slice(&version.to_le_bytes());
    o[22..24].copy_from_slice(&flags.to_le_bytes());
    seal(o)
}

/// Writes a blob's total length and its CRC-32 (of everything after the CRC) into its header,
/// and checks that the parser takes it.
fn seal(mut o: Vec<u8>) -> Result<Vec<u8>, BlobError> {
    let total = o.len() as u32;
    o[8..12].copy_from_slice(&total.to_le_bytes());
    let crc = CRC32.checksum(&o[16..]);
    o[12..16].copy_from_slice(&crc.to_le_bytes());
    Model::parse(&o)?;
    Ok(o)
}

impl ModelSpec {
    /// Whether layer `i` is written in the blocked order: a Dense of 4 output channels
    /// feeding a ConvTranspose2d, inputs a multiple of [`BLOCK`] (the board's fused kernel).
    pub fn blocked(&self, i: usize) -> bool {
        let (l, next) = (&self.layers[i], self.layers.get(i + 1));
        l.kind == LayerKind::Dense
            && l.output.c == 4
            && l.input.len().is_multiple_of(BLOCK)
            && next.is_some_and(|n| n.kind == LayerKind::ConvTranspose2d)
    }
}

/// The weight bytes of `l` (PyTorch order) in the blocked order.
fn block(l: &LayerSpec, w: &[u8]) -> Vec<u8> {
    let size = match l.weights {
        Weights::I8(_) => 1,
        Weights::I16(_) => 2,
    };
    let n_in = l.input.len();
    let (c_n, hw) = (l.output.c as usize, l.output.h as usize * l.output.w as usize);
    let mut out = vec![0u8; w.len()];
    for (i, v) in w.chunks_exact(size).enumerate() {
        let (o, j) = (i / n_in, i % n_in);
        let (c, px) = (o / hw, o % hw);
        let at = ((px * (n_in / BLOCK) + j / BLOCK) * c_n + c) * BLOCK + j % BLOCK;
        out[at * size..(at + 1) * size].copy_from_slice(v);
    }
    out
}

impl Reach {
    /// Builds the reach network from flat float rows (e.g. from safetensors).
    #[allow(clippy::too_many_arguments)] // the eight tensors of the published file, by name
    pub fn from_parts(
        w1: &[f32],
        b1: &[f32],
        w2: &[f32],
        b2: &[f32],
        in_min: [f32; REACH_IN],
        in_max: [f32; REACH_IN],
        out_min: [f32; REACH_OUT],
        out_max: [f32; REACH_OUT],
    ) -> Result<Reach, BlobError> {
        if w1.len() != REACH_HIDDEN * REACH_IN
            || b1.len() != REACH_HIDDEN
            || w2.len() != REACH_OUT * REACH_HIDDEN
            || b2.len() != REACH_OUT
        {
            return Err(BlobError::Reach);
        }
        let mut v = [0f32; REACH_FLOATS];
        let parts: [&[f32]; 8] = [w1, b1, w2, b2, &in_min, &in_max, &out_min, &out_max];
        let mut i = 0;
        for p in parts {
            v[i..i + p.len()].copy_from_slice(p);
            i += p.len();
        }
        let r = Reach::from_floats(&v);
        if r.is_valid() {
            Ok(r)
        } else {
            Err(BlobError::Reach)
        }
    }
}
