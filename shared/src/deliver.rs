//! The host's half of face-frame delivery (selective repeat, see [`crate::msg`]): what to send
//! next, what an ack means, when to poll; and the chunk size for a line.
//!
//! [`FaceSender`] holds no image and does no I/O: the caller keeps the pixels, writes what
//! [`FaceSender::next`] returns, tells it when the line went idle and hands it the board's acks.
//! So the same code drives the sim, QEMU and a serial port, and tests can drive it by hand.

use crate::blob::CRC32;
use crate::msg::{ChunkSet, CropAt, FrameAck, FrameHeader, FrameState, HostToBoard, CHUNK, MAX_FRAME_CHUNKS, MIN_CHUNK};

/// Wire bytes a face chunk costs beyond its data: message tag, frame id and offset varints and
/// length (5), frame header and CRC (5), COBS and delimiter (2), with a margin of one.
pub const CHUNK_OVERHEAD: usize = 13;

/// The byte error rate past which a face frame goes without its chroma planes. They add half
/// again to a frame; on a line that loses one 224-byte chunk in five (a byte error of 1e-3)
/// a frame with them came through so much later that the marks seen were not confirmed in
/// time (`msr mirror-test --ber 1e-3`: 18 of 44 marks touched with them, 40 of 44 without).
pub const COLOUR_MAX_BYTE_ERROR: f32 = 1e-3;

/// The header of a face image: chunk size `chunk` (clamped to what the protocol allows for this
/// size) and the image's CRC-32. `pixels` is the grey face, or the grey face and its chroma
/// planes ([`crate::blob::chroma`]; the header then says so).
pub fn face_header(frame: u16, crop: impl Into<CropAt>, size: [u16; 2], chunk: u16, pixels: &[u8]) -> FrameHeader {
    let n = size[0] as usize * size[1] as usize;
    let colour = pixels.len() == n + 2 * crate::blob::chroma::blocks(size[1] as usize, size[0] as usize);
    let least = if colour { pixels.len() } else { n }.div_ceil(MAX_FRAME_CHUNKS).max(MIN_CHUNK);
    let crop = crop.into();
    FrameHeader {
        frame,
        crop_x: crop.px[0],
        crop_y: crop.px[1],
        crop_sub: crop.sub,
        width: size[0],
        height: size[1],
        chunk: (chunk as usize).clamp(least, CHUNK) as u16,
        crc32: CRC32.checksum(pixels),
        colour,
    }
}

/// The chunk size that moves the most image bytes per line byte when each byte is damaged
/// with probability `byte_error` (independently): `c / (c + o) * (1 - p)^(c + o)`, over the
/// multiples of 8 in [`MIN_CHUNK`]`..=`[`CHUNK`]. A clean line gets [`CHUNK`].
pub fn chunk_for(byte_error: f32) -> u16 {
    let keep = (1.0 - byte_error).clamp(0.0, 1.0);
    let mut survive = 1.0f32; // keep^(c + o)
    for _ in 0..MIN_CHUNK + CHUNK_OVERHEAD {
        survive *= keep;
    }
    let step = keep * keep * keep * keep * keep * keep * keep * keep;
    let (mut best, mut best_eff) = (CHUNK, -1.0f32);
    let mut c = MIN_CHUNK;
    while c <= CHUNK {
        let eff = c as f32 / (c + CHUNK_OVERHEAD) as f32 * survive;
        // Ties go to the larger chunk (fewer messages).
        if eff >= best_eff {
            best = c;
            best_eff = eff;
        }
        c += 8;
        survive *= step;
    }
    best as u16
}

/// What one frame's delivery cost.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SendStats {
    /// Chunks written, first sends and repeats.
    pub chunks_sent: u32,
    /// Chunks written again because an ack listed them missing.
    pub chunks_resent: u32,
    /// `FramePoll`s written: one per round, and one after each timeout.
    pub polls: u32,
    /// Waits for an ack that ran out.
    pub timeouts: u32,
    /// Of the first round's chunks, how many the board missed, when it said so.
    pub first_round_missing: Option<(u16, u16)>,
}

/// Sends one face frame until the board has it whole (or says it is stale).
#[derive(Clone, Debug)]
pub struct FaceSender {
    header: FrameHeader,
    /// Chunks to write in this round.
    queue: ChunkSet,
    start_due: bool,
    poll_due: bool,
    round: u8,
    /// When the line went idle after this round; the ack timeout runs from then.
    wait_from: Option<u64>,
    timeout_us: u64,
    state: Option<FrameState>,
    /// What this frame's delivery has cost so far.
    pub stats: SendStats,
}

impl FaceSender {
    /// Starts a frame: `FrameStart`, every chunk and a `FramePoll`, then a wait for the board's
    /// ack (it answers the last chunk and the poll: two chances on a noisy line). No ack
    /// `timeout_us` after the line went idle: another `FramePoll`.
    pub fn new(header: FrameHeader, timeout_us: u64) -> FaceSender {
        FaceSender {
            header,
            queue: ChunkSet::first(header.chunks()),
            start_due: true,
            poll_due: true,
            round: 0,
            wait_from: None,
            timeout_us,
            state: None,
            stats: SendStats::default(),
        }
    }

    /// The header sent in `FrameStart` and every `FramePoll`.
    pub fn header(&self) -> &FrameHeader {
        &self.header
    }

    /// The board has the frame whole (`Complete`) or will never take it (`Stale`).
    pub fn finished(&self) -> Option<FrameState> {
        self.state
    }

    /// The next message to write, or `None` when the round is out (then [`Self::sent`]).
    pub fn next<'a>(&mut self, pixels: &'a [u8]) -> Option<HostToBoard<'a>> {
        if self.state.is_some() {
            return None;
        }
        if core::mem::take(&mut self.start_due) {
            return Some(HostToBoard::FrameStart(self.header));
        }
        if let Some(i) = self.queue.first_member() {
            self.queue.remove(i);
            self.stats.chunks_sent += 1;
            if self.round > 0 {
                self.stats.chunks_resent += 1;
            }
            let r = self.header.chunk_range(i);
            let data = pixels.get(r.clone()).unwrap_or(&[]);
            return Some(HostToBoard::FrameChunk { frame: self.header.frame, offset: r.start as u16, data });
        }
        if core::mem::take(&mut self.poll_due) {
            self.stats.polls += 1;
            return Some(HostToBoard::FramePoll { header: self.header, round: self.round });
        }
        None
    }

    /// Everything [`Self::next`] gave is written; the line is idle at `idle_at_us`.
    pub fn sent(&mut self, idle_at_us: u64) {
        if self.wait_from.is_none() && self.queue.is_empty() && !self.poll_due && !self.start_due {
            self.wait_from = Some(idle_at_us);
        }
    }

    /// Call now and then: after the timeout without an ack, polls (same round) again.
    pub fn check(&mut self, now_us: u64) {
        if self.state.is_some() {
            return;
        }
        if let Some(t) = self.wait_from {
            if now_us >= t.saturating_add(self.timeout_us) {
                self.wait_from = None;
                self.poll_due = true;
                self.stats.timeouts += 1;
            }
        }
    }

    /// The board's ack. Acks of other frames and late acks of earlier rounds are ignored.
    pub fn on_ack(&mut self, ack: &FrameAck) {
        if ack.frame != self.header.frame || self.state.is_some() {
            return;
        }
        match ack.state {
            FrameState::Complete | FrameState::Stale => self.state = Some(ack.state),
            FrameState::Missing(set) => {
                if ack.round != self.round {
                    return;
                }
                let n = self.header.chunks();
                if self.round == 0 && set.len() < n {
                    // All missing means the FrameStart was lost: no word on the line.
                    self.stats.first_round_missing = Some((set.len() as u16, n as u16));
                }
                self.queue = set;
                // Round numbers skip 0, which the board's own acks carry.
                self.round = self.round.wrapping_add(1).max(1);
                self.poll_due = true;
                self.wait_from = None;
            }
        }
    }

    /// The board reported a detection for this frame: it ran the pipeline on it.
    pub fn on_detection(&mut self, frame: u16) {
        if frame == self.header.frame && self.state.is_none() {
            self.state = Some(FrameState::Complete);
        }
    }
}

/// A running estimate of the line's byte error rate from how many first-round chunks the board
/// missed, and the chunk size for it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LineEstimate {
    /// Byte error probability, smoothed over frames.
    pub byte_error: f32,
}

impl LineEstimate {
    /// Weight of the newest frame.
    const GAIN: f32 = 0.5;

    /// Learns from one frame's first round: `missing` of `sent` chunks of `chunk` data bytes.
    pub fn learn(&mut self, missing: u16, sent: u16, chunk: u16) {
        if sent == 0 {
            return;
        }
        // A chunk of w bytes survives with (1 - p)^w: invert on the frame's loss.
        let lost = (missing as f32 / sent as f32).min(0.99);
        let w = (chunk as usize + CHUNK_OVERHEAD) as f32;
        let p = 1.0 - root(1.0 - lost, w);
        self.byte_error += Self::GAIN * (p - self.byte_error);
    }

    /// The chunk size for the current estimate ([`chunk_for`]).
    pub fn chunk(&self) -> u16 {
        chunk_for(self.byte_error)
    }
}

/// `x^(1/w)` for x in (0, 1], w >= 1, by bisection (no `libm` in this crate).
fn root(x: f32, w: f32) -> f32 {
    let (mut lo, mut hi) = (0.0f32, 1.0f32);
    for _ in 0..32 {
        let mid = 0.5 * (lo + hi);
        if pow(mid, w) < x {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// `b^e` for b in [0, 1] and whole-ish e >= 0, by squaring.
fn pow(b: f32, e: f32) -> f32 {
    let mut n = e as u32;
    let (mut acc, mut base) = (1.0f32, b);
    while n > 0 {
        if n & 1 == 1 {
            acc *= base;
        }
        base *= base;
        n >>= 1;
    }
    acc
}

/// What a [`FaceLink`] did, for goodput and retransmission reports.
#[cfg(any(feature = "std", test))]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct LinkStats {
    /// Frames started.
    pub frames: u32,
    /// Frames the board took whole.
    pub delivered: u32,
    /// Frames given up for a newer one before the board had them whole.
    pub superseded: u32,
    /// Image bytes of the delivered frames.
    pub face_bytes: u64,
    /// Chunks written, first sends and repeats.
    pub chunks_sent: u64,
    /// Chunks sent again (selective repeat).
    pub chunks_resent: u64,
    /// `FramePoll`s written.
    pub polls: u64,
    /// Waits for an ack that ran out (each followed by another poll).
    pub timeouts: u64,
}

#[cfg(any(feature = "std", test))]
impl LinkStats {
    /// Adds another run's counts into these.
    pub fn add(&mut self, o: &LinkStats) {
        self.frames += o.frames;
        self.delivered += o.delivered;
        self.superseded += o.superseded;
        self.face_bytes += o.face_bytes;
        self.chunks_sent += o.chunks_sent;
        self.chunks_resent += o.chunks_resent;
        self.polls += o.polls;
        self.timeouts += o.timeouts;
    }
}

/// The host's face-frame stream: one frame in flight at a time, a newer one supersedes it, the
/// chunk size follows the line ([`LineEstimate`]) unless fixed.
#[cfg(any(feature = "std", test))]
#[derive(Clone, Debug)]
pub struct FaceLink {
    /// The line's byte error rate, learnt from the acks; sets the chunk size.
    pub estimate: LineEstimate,
    /// `Some(c)`: always chunks of `c` bytes.
    pub fixed_chunk: Option<u16>,
    timeout_us: u64,
    frame_id: u16,
    current: Option<InFlight>,
    /// Totals over every frame sent.
    pub stats: LinkStats,
}

#[cfg(any(feature = "std", test))]
#[derive(Clone, Debug)]
struct InFlight {
    sender: FaceSender,
    pixels: Vec<u8>,
    started_us: u64,
    /// The first round taught the estimate already.
    learned: bool,
}

#[cfg(any(feature = "std", test))]
impl FaceLink {
    /// `timeout_us`: how long after the line went idle an ack may take (a poll follows).
    pub fn new(timeout_us: u64) -> FaceLink {
        FaceLink {
            estimate: LineEstimate::default(),
            fixed_chunk: None,
            timeout_us,
            frame_id: 0,
            current: None,
            stats: LinkStats::default(),
        }
    }

    /// Moves the next frame id `n` ahead. A board keeps the id it last completed across host
    /// sessions: a session whose ids start again where an earlier one's were would have its
    /// frames taken for old ones (ignored, or acked `Complete` without being run).
    pub fn skip_ids(&mut self, n: u16) {
        self.frame_id = self.frame_id.wrapping_add(n);
    }

    /// When the frame in flight started, if one is.
    pub fn in_flight_since(&self) -> Option<u64> {
        self.current.as_ref().map(|c| c.started_us)
    }

    /// Starts a frame (superseding one in flight); returns its id. `pixels` is the grey face,
    /// or the grey face and its chroma planes: on a line whose byte errors exceed
    /// [`COLOUR_MAX_BYTE_ERROR`] the planes stay behind and the board sees grey.
    pub fn start(&mut self, crop: impl Into<CropAt>, size: [u16; 2], mut pixels: Vec<u8>, now_us: u64) -> u16 {
        if self.estimate.byte_error > COLOUR_MAX_BYTE_ERROR {
            pixels.truncate(size[0] as usize * size[1] as usize);
        }
        if let Some(c) = self.current.take() {
            self.stats.superseded += 1;
            self.count(&c.sender);
        }
        self.frame_id = self.frame_id.wrapping_add(1);
        let chunk = self.fixed_chunk.unwrap_or_else(|| self.estimate.chunk());
        let h = face_header(self.frame_id, crop, size, chunk, &pixels);
        let sender = FaceSender::new(h, self.timeout_us);
        self.current = Some(InFlight { sender, pixels, started_us: now_us, learned: false });
        self.stats.frames += 1;
        self.frame_id
    }

    /// Hands every message due now to `write`; returns how many. Then call [`Self::sent`].
    pub fn pump(&mut self, mut write: impl FnMut(&HostToBoard)) -> usize {
        let Some(c) = self.current.as_mut() else { return 0 };
        let mut n = 0;
        while let Some(m) = c.sender.next(&c.pixels) {
            write(&m);
            n += 1;
        }
        n
    }

    /// What [`Self::pump`] wrote will have left by `idle_at_us`.
    pub fn sent(&mut self, idle_at_us: u64) {
        if let Some(c) = self.current.as_mut() {
            c.sender.sent(idle_at_us);
        }
    }

    /// Runs the ack timeout.
    pub fn check(&mut self, now_us: u64) {
        if let Some(c) = self.current.as_mut() {
            c.sender.check(now_us);
        }
    }

    /// A message from the board. Returns the id of a frame that just got through whole.
    pub fn on_message(&mut self, m: &crate::msg::BoardToHost) -> Option<u16> {
        use crate::msg::BoardToHost;
        let c = self.current.as_mut()?;
        match m {
            BoardToHost::FrameAck(a) => c.sender.on_ack(a),
            BoardToHost::Detection(d) => c.sender.on_detection(d.frame),
            _ => return None,
        }
        // Learn from the first round as soon as it is known, whether or not the frame ends.
        let st = c.sender.stats;
        let h = *c.sender.header();
        let first = match (st.first_round_missing, c.sender.finished()) {
            (Some(m), _) => Some(m),
            (None, Some(FrameState::Complete)) if st.chunks_resent == 0 => Some((0, h.chunks() as u16)),
            _ => None,
        };
        if let (false, Some((missing, of))) = (c.learned, first) {
            c.learned = true;
            self.estimate.learn(missing, of, h.chunk);
        }
        let state = c.sender.finished()?;
        let c = self.current.take()?;
        self.count(&c.sender);
        if state != FrameState::Complete {
            self.stats.superseded += 1;
            return None;
        }
        self.stats.delivered += 1;
        self.stats.face_bytes += c.pixels.len() as u64;
        Some(h.frame)
    }

    fn count(&mut self, s: &FaceSender) {
        self.stats.chunks_sent += s.stats.chunks_sent as u64;
        self.stats.chunks_resent += s.stats.chunks_resent as u64;
        self.stats.polls += s.stats.polls as u64;
        self.stats.timeouts += s.stats.timeouts as u64;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(n_chunks_of_224: usize) -> FrameHeader {
        let pixels = vec![7u8; 58 * 75];
        let h = face_header(9, [1, 2], [58, 75], 224, &pixels);
        assert_eq!(h.chunks(), n_chunks_of_224);
        h
    }

    #[test]
    fn chunk_size_follows_the_line() {
        assert_eq!(chunk_for(0.0), CHUNK as u16);
        // BER 1e-4 and 1e-3 per bit: about 8e-4 and 8e-3 per byte.
        let mid = chunk_for(8e-4);
        let noisy = chunk_for(8e-3);
        assert!((96..=136).contains(&mid), "{mid}");
        assert!((24..=40).contains(&noisy), "{noisy}");
        assert_eq!(chunk_for(0.5), MIN_CHUNK as u16);
    }

    #[test]
    fn face_header_clamps_the_chunk() {
        let pixels = vec![0u8; 96 * 64];
        assert_eq!(face_header(1, [0, 0], [96, 64], 8, &pixels).chunk, 24);
        assert_eq!(face_header(1, [0, 0], [96, 64], 999, &pixels).chunk, 224);
        assert_eq!(face_header(1, [0, 0], [96, 64], 100, &pixels).crc32, CRC32.checksum(&pixels));
    }

    #[test]
    fn estimate_inverts_the_loss() {
        let mut e = LineEstimate::default();
        for _ in 0..20 {
            // 1 - (1 - 8e-4)^237 = 17.3 % of 224-byte chunks lost.
            e.learn(173, 1000, 224);
        }
        assert!((e.byte_error - 8e-4).abs() < 1e-4, "{}", e.byte_error);
        assert!((0.1..0.2).contains(&(1.0 - pow(1.0 - 8e-4, 237.0))));
    }

    #[test]
    fn a_clean_frame_is_start_chunks_poll_and_one_wait() {
        let h = header(20);
        let px = vec![7u8; h.pixels()];
        let mut s = FaceSender::new(h, 5000);
        assert!(matches!(s.next(&px), Some(HostToBoard::FrameStart(x)) if x == h));
        for i in 0..20 {
            match s.next(&px) {
                Some(HostToBoard::FrameChunk { frame: 9, offset, data }) => {
                    assert_eq!(offset as usize, i * 224);
                    assert_eq!(data.len(), if i == 19 { 94 } else { 224 });
                }
                other => panic!("{other:?}"),
            }
        }
        assert_eq!(s.next(&px), Some(HostToBoard::FramePoll { header: h, round: 0 }));
        assert_eq!(s.next(&px), None);
        s.sent(1000);
        s.check(5999);
        assert_eq!(s.next(&px), None);
        s.on_ack(&FrameAck { frame: 9, round: 0, state: FrameState::Complete });
        assert_eq!(s.finished(), Some(FrameState::Complete));
        s.check(1_000_000);
        assert_eq!(s.next(&px), None);
        assert_eq!(s.stats, SendStats { chunks_sent: 20, polls: 1, ..Default::default() });
    }

    #[test]
    fn missing_chunks_are_resent_then_polled() {
        let h = header(20);
        let px = vec![7u8; h.pixels()];
        let mut s = FaceSender::new(h, 5000);
        while s.next(&px).is_some() {}
        s.sent(100);
        let mut m = ChunkSet::EMPTY;
        m.insert(3);
        m.insert(17);
        // An ack of another frame, or of a later round, changes nothing.
        s.on_ack(&FrameAck { frame: 8, round: 0, state: FrameState::Missing(m) });
        s.on_ack(&FrameAck { frame: 9, round: 4, state: FrameState::Missing(m) });
        assert_eq!(s.next(&px), None);
        s.on_ack(&FrameAck { frame: 9, round: 0, state: FrameState::Missing(m) });
        let offsets: Vec<_> = core::iter::from_fn(|| s.next(&px))
            .map(|m| match m {
                HostToBoard::FrameChunk { offset, .. } => offset as i32,
                HostToBoard::FramePoll { round, .. } => -(round as i32),
                other => panic!("{other:?}"),
            })
            .collect();
        assert_eq!(offsets, vec![3 * 224, 17 * 224, -1]);
        assert_eq!(s.stats.first_round_missing, Some((2, 20)));
        assert_eq!(s.stats.chunks_resent, 2);
        // The poll's ack is lost: after the timeout, the same round is polled again.
        s.sent(200);
        s.check(5199);
        assert_eq!(s.next(&px), None);
        s.check(5200);
        assert_eq!(s.next(&px), Some(HostToBoard::FramePoll { header: h, round: 1 }));
        assert_eq!(s.stats.timeouts, 1);
        s.on_detection(9);
        assert_eq!(s.finished(), Some(FrameState::Complete));
    }

    #[test]
    fn a_face_link_learns_the_line_and_counts() {
        use crate::msg::BoardToHost;
        let mut l = FaceLink::new(5000);
        let px = vec![1u8; 58 * 75];
        let a = l.start([0, 0], [58, 75], px.clone(), 0);
        let mut msgs = Vec::new();
        assert_eq!(l.pump(|m| msgs.push(format!("{m:?}"))), 22);
        l.sent(100);
        // Half the first round lost: the estimate rises, the next frame's chunks shrink.
        let mut m = ChunkSet::EMPTY;
        for i in 0..10 {
            m.insert(2 * i);
        }
        let ack = |frame, round, state| BoardToHost::FrameAck(FrameAck { frame, round, state });
        assert_eq!(l.on_message(&ack(a, 0, FrameState::Missing(m))), None);
        assert!(l.estimate.byte_error > 1e-3, "{:?}", l.estimate);
        assert_eq!(l.pump(|_| {}), 11, "ten chunks and a poll");
        // Superseded before it finished.
        let b = l.start([0, 0], [58, 75], px.clone(), 200_000);
        assert!(l.fixed_chunk.is_none());
        assert!(l.pump(|_| {}) > 22, "smaller chunks now");
        assert_eq!(l.on_message(&ack(a, 1, FrameState::Complete)), None, "an old frame's ack");
        assert_eq!(l.on_message(&ack(b, 0, FrameState::Complete)), Some(b));
        assert_eq!(l.in_flight_since(), None);
        let s = l.stats;
        assert_eq!((s.frames, s.delivered, s.superseded, s.face_bytes), (2, 1, 1, 4350));
        assert_eq!(s.chunks_resent, 10);
        assert_eq!(s.polls, 3);
    }

    #[test]
    fn a_noisy_line_leaves_the_chroma_planes_behind() {
        use crate::msg::HostToBoard;
        let n = 58 * 75;
        let colour = vec![9u8; n + 2 * crate::blob::chroma::blocks(75, 58)];
        let header = |l: &mut FaceLink| {
            let mut h = None;
            l.pump(|m| {
                if let HostToBoard::FrameStart(x) = m {
                    h = Some(*x);
                }
            });
            h.expect("a frame start")
        };
        let mut l = FaceLink::new(5000);
        l.start([0, 0], [58, 75], colour.clone(), 0);
        let h = header(&mut l);
        assert!(h.colour && h.bytes() == colour.len(), "a clean line carries the planes");
        l.estimate.byte_error = 2.0 * COLOUR_MAX_BYTE_ERROR;
        l.start([0, 0], [58, 75], colour.clone(), 1);
        let h = header(&mut l);
        assert!(!h.colour && h.bytes() == n, "a noisy one the grey alone");
        assert_eq!(h.crc32, crate::blob::CRC32.checksum(&colour[..n]));
    }
}
