//! Messages of the two serial links. Each is one postcard payload inside one [`crate::frame`].
//!
//! - Host link (a PC or the sim, to the board): [`HostToBoard`] and [`BoardToHost`].
//! - Servo bus (the board, to the joint servos): [`BoardToServo`] and [`ServoToBoard`].
//!
//! Large things (a face image, a model blob) travel in chunks so that every frame stays below
//! [`crate::frame::MAX_PAYLOAD`] and a damaged frame costs one chunk, which is sent again.
//!
//! # Face frames: selective repeat
//!
//! The host sends `FrameStart(h)`, then the chunks `FrameChunk { frame, offset, data }` with
//! `offset = i * h.chunk` for chunk `i` (every chunk `h.chunk` bytes, the last one the rest).
//! The host picks `h.chunk` in [`MIN_CHUNK`]`..=`[`CHUNK`] for the line
//! ([`crate::deliver::chunk_for`]: large on a clean line, small on a noisy one), at most
//! [`MAX_FRAME_CHUNKS`] chunks a frame. `h.crc32` is the CRC-32 of the whole image.
//!
//! The board (`msr_firmware::link::Assembly`) keeps **one** frame in progress: its header, the
//! [`ChunkSet`] of missing chunks ([`BITMAP_BYTES`] bytes) and the image buffer
//! (`MAX_FACE_PIXELS` bytes), all static; nothing else is buffered for face frames.
//!
//! | event on the board | what it does |
//! |---|---|
//! | `FrameStart`/`FramePoll` for a newer frame (or none in progress) | drops the unfinished frame (counted as superseded) and starts this one |
//! | the same for the frame in progress | a duplicate: ignored (a poll is answered) |
//! | the same for an older frame (fewer than [`STALE_WINDOW`] ids back) | stale: ignored, a poll answered [`FrameState::Stale`] |
//! | a chunk of the frame in progress | stored and marked, unless already there (a duplicate, ignored) |
//! | a chunk of another frame, or before its header | dropped (reordered or stale); the host's poll recovers it |
//! | a chunk of the wrong length or offset | refused (`BadFrame`), the frame in progress is kept |
//! | the last chunk (`i = n - 1`) of a frame still missing some | answers [`FrameAck`] round 0 with the missing set |
//! | `FramePoll { header, round }` | answers [`FrameAck`] for that round: missing set, `Complete`, or `Stale` |
//! | every chunk present | checks `crc32`; on a match answers `Complete` and runs the pipeline **once**; on a mismatch marks every chunk missing again and answers so |
//!
//! Reordering is thus handled by offsets (chunks may come in any order), duplication by the
//! missing set and the last completed frame id, loss by the host. The host
//! ([`crate::deliver::FaceSender`]) sends round 0 (`FrameStart`, every chunk, `FramePoll` round
//! 0), then waits for that round's ack; each ack listing missing chunks starts the next round:
//! those chunks and a `FramePoll` with the new round number. Acks of other rounds or frames are
//! ignored (late duplicates); no ack within its timeout after the line went idle, it polls the
//! same round again. A `Complete` ack or a [`Detection`] of the frame ends it; a frame that is
//! not complete by the host's deadline (two frame periods in the episodes) is superseded by a
//! fresh camera frame. So the board never runs the pipeline on a stale or partial image, nor on
//! one with a corrupted byte (CRC-16 per chunk, CRC-32 over the image), and runs it once per
//! frame id.
//!
//! The self gate (protocol 3, its statistics and the sub-pixel crop position 4): when the model has one, a confirmed mark does not start the
//! reach at once. The board answers that frame's `Detection` with `confirmed: false`, turns
//! its head for the probe (`Mode::SelfTest`; no detections while it runs), and sends one
//! [`BoardToHost::SelfGate`] with the decision. On a pass the reach starts and the board sends
//! a `Detection` with `confirmed: true`, no blob and the reach target, for the frame that
//! decided; it is repeated while the arm is up, like any reach.
//!
//! Board to host, nothing is repeated but the reach: while the arm is up the board answers each
//! whole frame with the [`Detection`] that started the reach (same frame id), so a host that
//! lost it still learns of the reach; a host takes a confirmed detection once per frame id.
//! Other lost reports (detections, errors, statuses) are not recovered: the next frame brings a
//! new one.
//!
//! Bounds. Board: one image buffer (`MAX_FACE_PIXELS` = 6144 bytes), one [`FrameHeader`], one
//! [`ChunkSet`] (32 bytes), the last completed id, the last reach (one [`Detection`]); the
//! receive accumulator of [`crate::frame`] (264 bytes) per link; the model staging area of the
//! store. Host: one frame in flight (its pixels and a [`ChunkSet`]); nothing grows with loss.
//!
//! # Model uploads: go-back to the last good chunk
//!
//! `ModelBegin { len, crc32 }` answers [`BoardToHost::UploadAck`] with the offset the board
//! wants next: 0 for a new upload, or how far an unfinished upload of the same `len` and `crc32`
//! got (a resumed upload, e.g. after the host restarted). The board takes `ModelChunk`s only in
//! order: a duplicate (already stored) is ignored, a chunk past a gap is dropped and answered
//! once with `UploadAck` (the host goes back to that offset). `ModelCommit` before all bytes
//! arrived answers `UploadAck` too and keeps what arrived. The staging area is the only buffer
//! (the store's capacity); chunks are written once, in order, so flash works as staging.
//!
//! # Versions
//!
//! Every frame carries [`crate::frame::PROTOCOL_VERSION`]. A board that receives a frame of
//! another version answers [`ErrorCode::Version`] (detail: the version it got) and drops it; a
//! host that receives one stops with an error naming both versions.

use crate::blob::{Normalisation, Sided};
use crate::joints::Joint;
use serde::{Deserialize, Serialize};

/// Largest data chunk in a frame or model chunk message.
pub const CHUNK: usize = 224;
/// Smallest face chunk a host may choose.
pub const MIN_CHUNK: usize = 24;
/// Most chunks in one face frame.
pub const MAX_FRAME_CHUNKS: usize = 256;
/// Bytes of a [`ChunkSet`].
pub const BITMAP_BYTES: usize = MAX_FRAME_CHUNKS / 8;
/// A frame id this many or more behind the board's current one is a restarted host, not stale.
pub const STALE_WINDOW: u16 = 64;
/// Most joints in one servo-bus message: head and both arms.
pub const MAX_BUS_JOINTS: usize = 14;

/// Steps of [`FrameHeader::crop_sub`] per pixel.
pub const SUB_PER_PX: i8 = 64;
/// Largest [`FrameHeader::crop_sub`] either way: one pixel (the face lies within half a pixel
/// of where it was cut, and that within half a pixel of `crop_x`).
pub const SUB_MAX: i8 = SUB_PER_PX;

/// The sub-pixel part of a crop position `shift` pixels off the whole-pixel one, in
/// [`FrameHeader::crop_sub`]'s steps (rounded, clamped to a pixel; 0 when not finite).
pub fn crop_sub(shift: f32) -> i8 {
    if !shift.is_finite() {
        return 0;
    }
    let v = (shift * SUB_PER_PX as f32).clamp(-(SUB_MAX as f32), SUB_MAX as f32);
    // Round half away from zero (`f32::round` is not in `core`).
    (v + if v >= 0.0 { 0.5 } else { -0.5 }) as i8
}

/// Where a face crop was cut in the full frame: whole pixels and the sub-pixel rest, as the
/// frame header carries them. A `[u16; 2]` is a whole-pixel crop.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CropAt {
    /// `crop_x`, `crop_y`.
    pub px: [u16; 2],
    /// `crop_sub`.
    pub sub: [i8; 2],
}

impl CropAt {
    /// A crop at whole pixels `px`, the face `shift` pixels off them (within a pixel).
    pub fn subpixel(px: [u16; 2], shift: [f32; 2]) -> CropAt {
        CropAt { px, sub: shift.map(crop_sub) }
    }
}

impl From<[u16; 2]> for CropAt {
    fn from(px: [u16; 2]) -> CropAt {
        CropAt { px, sub: [0; 2] }
    }
}

/// Announces a face image; its pixels follow in [`HostToBoard::FrameChunk`]s.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FrameHeader {
    /// Frame number chosen by the host; chunks name it.
    pub frame: u16,
    /// Where the face crop sits in the full camera frame (pixels), for full-frame reports and
    /// the reach network's input; the nearest whole pixel when the host cropped at sub-pixel
    /// precision (`blob::CropMode::Subpixel`), so within half a pixel of where it was cut.
    pub crop_x: u16,
    /// See `crop_x`.
    pub crop_y: u16,
    /// Where the face lies relative to `crop_x`, `crop_y`, `[x, y]` in 1/[`SUB_PER_PX`] pixel,
    /// within +-[`SUB_MAX`] (a pixel): the face lies at `crop_x + crop_sub[0] / SUB_PER_PX`,
    /// as the host's template alignment finds it (the crop itself was cut within half a pixel
    /// of `crop_x`). Zero for a whole-pixel crop. The self gate follows the face to a fraction
    /// of a pixel.
    pub crop_sub: [i8; 2],
    /// Crop size; must equal the model's face size.
    pub width: u16,
    /// Crop height in pixels; must equal the model's face height.
    pub height: u16,
    /// Chunk size of this frame, [`MIN_CHUNK`]`..=`[`CHUNK`].
    pub chunk: u16,
    /// CRC-32 (ISO-HDLC, as blobs) of the whole image.
    pub crc32: u32,
}

impl FrameHeader {
    /// Pixels in the image.
    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Chunks the image travels in (0 when `chunk` is 0).
    pub fn chunks(&self) -> usize {
        if self.chunk == 0 {
            return 0;
        }
        self.pixels().div_ceil(self.chunk as usize)
    }

    /// Chunk size in range, at most [`MAX_FRAME_CHUNKS`] chunks, a non-empty image, the
    /// sub-pixel part within a pixel.
    pub fn is_valid(&self) -> bool {
        (MIN_CHUNK..=CHUNK).contains(&(self.chunk as usize))
            && self.pixels() > 0
            && self.chunks() <= MAX_FRAME_CHUNKS
            && self.crop_sub.iter().all(|s| s.unsigned_abs() <= SUB_MAX as u8)
    }

    /// Where the face crop sits in the full frame, `[x, y]` pixels, sub-pixel part included.
    pub fn position(&self) -> [f32; 2] {
        [
            self.crop_x as f32 + self.crop_sub[0] as f32 / SUB_PER_PX as f32,
            self.crop_y as f32 + self.crop_sub[1] as f32 / SUB_PER_PX as f32,
        ]
    }

    /// Where chunk `i` lies in the image.
    pub fn chunk_range(&self, i: usize) -> core::ops::Range<usize> {
        let start = i * self.chunk as usize;
        start.min(self.pixels())..(start + self.chunk as usize).min(self.pixels())
    }

    /// Is `frame` older than this header's frame by less than [`STALE_WINDOW`]?
    pub fn is_stale(&self, frame: u16) -> bool {
        is_older(frame, self.frame)
    }
}

/// Is frame id `a` behind `b` by 1 to [`STALE_WINDOW`]` - 1` (wrapping)?
pub fn is_older(a: u16, b: u16) -> bool {
    let back = b.wrapping_sub(a);
    back != 0 && back < STALE_WINDOW
}

/// One bit per chunk of a face frame, [`MAX_FRAME_CHUNKS`] of them. On the wire: the bitmap up
/// to its last non-zero byte, with a length (an ack is short when few chunks are missing, and a
/// short ack is less likely to be hit on a noisy line).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(into = "Trimmed", from = "Trimmed")]
pub struct ChunkSet([u8; BITMAP_BYTES]);

type Trimmed = heapless::Vec<u8, BITMAP_BYTES>;

impl From<ChunkSet> for Trimmed {
    fn from(s: ChunkSet) -> Trimmed {
        let used = s.0.iter().rposition(|b| *b != 0).map_or(0, |i| i + 1);
        Trimmed::from_slice(&s.0[..used]).unwrap_or_default()
    }
}

impl From<Trimmed> for ChunkSet {
    fn from(v: Trimmed) -> ChunkSet {
        let mut s = ChunkSet::EMPTY;
        s.0[..v.len()].copy_from_slice(&v);
        s
    }
}

impl ChunkSet {
    /// No chunks.
    pub const EMPTY: ChunkSet = ChunkSet([0; BITMAP_BYTES]);

    /// Chunks `0..n`.
    pub fn first(n: usize) -> ChunkSet {
        let mut s = ChunkSet::EMPTY;
        for i in 0..n.min(MAX_FRAME_CHUNKS) {
            s.insert(i);
        }
        s
    }

    /// Whether chunk `i` is a member (false for `i` >= [`MAX_FRAME_CHUNKS`]).
    pub fn contains(&self, i: usize) -> bool {
        i < MAX_FRAME_CHUNKS && self.0[i / 8] & (1 << (i % 8)) != 0
    }

    /// Adds chunk `i`; ignored for `i` >= [`MAX_FRAME_CHUNKS`].
    pub fn insert(&mut self, i: usize) {
        if i < MAX_FRAME_CHUNKS {
            self.0[i / 8] |= 1 << (i % 8);
        }
    }

    /// Removes `i`; returns whether it was there.
    pub fn remove(&mut self, i: usize) -> bool {
        let had = self.contains(i);
        if had {
            self.0[i / 8] &= !(1 << (i % 8));
        }
        had
    }

    /// Number of members.
    pub fn len(&self) -> usize {
        self.0.iter().map(|b| b.count_ones() as usize).sum()
    }

    /// No members.
    pub fn is_empty(&self) -> bool {
        self.0.iter().all(|b| *b == 0)
    }

    /// The smallest member.
    pub fn first_member(&self) -> Option<usize> {
        let (byte, b) = self.0.iter().enumerate().find(|(_, b)| **b != 0)?;
        Some(byte * 8 + b.trailing_zeros() as usize)
    }

    /// The members in increasing order.
    pub fn iter(&self) -> impl Iterator<Item = usize> + '_ {
        (0..MAX_FRAME_CHUNKS).filter(|i| self.contains(*i))
    }

    /// The bitmap, bit `i % 8` of byte `i / 8` for chunk `i`.
    pub fn bytes(&self) -> &[u8; BITMAP_BYTES] {
        &self.0
    }
}

/// Where a face frame stands on the board.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum FrameState {
    /// All chunks arrived and the image passed its CRC-32; the pipeline ran on it once.
    Complete,
    /// In progress: these chunks are missing.
    Missing(ChunkSet),
    /// An older frame than the one in progress: it will never be processed.
    Stale,
}

/// The board's answer about one face frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FrameAck {
    /// The face frame's id, as in its [`FrameHeader`].
    pub frame: u16,
    /// The `FramePoll` round answered; 0 for acks the last chunk or completion triggered.
    pub round: u8,
    /// Complete, stale, or the chunks still missing.
    pub state: FrameState,
}

/// Run-time settings the host may change. Out-of-range values are refused by the board.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Config {
    /// Saliency threshold in units of the normalisation (sigma or sigma^2).
    pub threshold: f32,
    /// Whether `threshold` divides by sigma or sigma^2.
    pub normalisation: Normalisation,
    /// One-sided (`(e - mu) / n > t`) or two-sided (`|e - mu| / n > t`) test.
    pub sided: Sided,
    /// Smallest blob, in pixels, that counts as a mark.
    pub min_area: u16,
    /// A mark must be seen in `confirm_k` of the last `confirm_n` frames before a reach.
    pub confirm_k: u8,
    /// Window length of the confirmation filter (`confirm_k <= confirm_n`).
    pub confirm_n: u8,
    /// Fraction of each joint's maximum velocity used when moving.
    pub speed_fraction: f32,
    /// How long a reach is held before returning home.
    pub hold_ms: u32,
}

/// Host to board.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum HostToBoard<'a> {
    /// Asks the board whether it is alive; it answers [`BoardToHost::Pong`] with the same nonce.
    Ping {
        /// Any value; echoed back so the host can match the answer.
        nonce: u32,
    },
    /// Announces a face image (see the module docs); without a model the board answers [`ErrorCode::NoModel`].
    FrameStart(FrameHeader),
    /// Part of a face image; a chunk of the wrong length or offset is refused with [`ErrorCode::BadFrame`].
    FrameChunk {
        /// The frame id of its [`FrameStart`](HostToBoard::FrameStart).
        frame: u16,
        /// Byte offset of `data` in the row-major grey image.
        offset: u16,
        #[serde(borrow)]
        /// `chunk` pixels (the last chunk: the rest), one grey byte each.
        data: &'a [u8],
    },
    /// Starts a model upload of `len` bytes whose CRC-32 (ISO-HDLC) is `crc32`.
    ModelBegin {
        /// Blob length in bytes; more than the store's capacity is refused ([`ErrorCode::BadUpload`]).
        len: u32,
        /// CRC-32 of the whole blob; a matching unfinished upload resumes.
        crc32: u32,
    },
    /// Part of a model upload, taken only in order; a gap is answered by [`BoardToHost::UploadAck`].
    ModelChunk {
        /// Byte offset of `data` in the blob.
        offset: u32,
        #[serde(borrow)]
        /// At most [`CHUNK`] bytes of the blob.
        data: &'a [u8],
    },
    /// Validates the uploaded blob and switches to it; the old model stays if it is bad.
    ModelCommit,
    /// New run-time settings; applied whole, or refused with [`ErrorCode::BadConfig`].
    Configure(Config),
    /// Asks for a [`BoardToHost::Status`].
    GetStatus,
    /// Asks where a face frame stands; starts it if the board has not seen its `FrameStart`.
    FramePoll {
        /// The frame's header, as in its `FrameStart`.
        header: FrameHeader,
        /// The host's round number (0 for the first round), echoed in the [`FrameAck`].
        round: u8,
    },
    /// Chooses the servo bus protocol; the Dynamixel master starts up anew.
    UseServoBus(ServoBusKind),
    /// A new Dynamixel joint map (refused as a whole with [`ErrorCode::BadServoMap`]); the
    /// servo bus then speaks Dynamixel, and its start-up runs again.
    SetServoMap([crate::dynamixel::map::JointMapEntry; crate::dynamixel::map::MAP_JOINTS]),
    /// Asks for [`BoardToHost::ServoBus`].
    GetServoBus,
    /// Moves the head to (HeadYaw, HeadPitch), radians, at the configured speed fraction, the
    /// arm staying where it is. Answered by [`BoardToHost::HeadAt`] (the reported angles) once the
    /// servos hold still within eight encoder counts of the pose (a loaded pitch servo may hold a
    /// few counts off its goal), or by [`ErrorCode::HeadRefused`] / [`ErrorCode::HeadNotSettled`].
    /// Only while observing (not during a reach); an angle outside the joint's limits is refused,
    /// not clamped. Counts as host activity for the face watchdog (head babbling sends no
    /// frames). `yaw`, `pitch`: HeadYaw and HeadPitch, radians.
    #[allow(missing_docs)]
    MoveHead { yaw: f32, pitch: f32 },
    /// Asks for [`BoardToHost::Store`]: where the running model came from, the saved statistics.
    GetStore,
    /// Back to the model's own statistics: the saved ones are dropped (in flash too), and what
    /// the board learnt of the room ([`RoomCommand::Reset`]); answered by [`BoardToHost::Store`].
    ResetStats,
    /// Controls the board's online self-calibration (what it learns of the room's light);
    /// answered by [`BoardToHost::Status`], or by [`BoardToHost::Store`] for a save.
    Room(RoomCommand),
}

/// What the host asks of the board's online self-calibration.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum RoomCommand {
    /// Stop learning; what was learnt stays in use.
    Freeze,
    /// Learn again.
    Resume,
    /// Back to the model's calibrated statistics (offsets 0; the saved ones dropped too).
    Reset,
    /// Save what was learnt now (the board also saves every few minutes), in a store that
    /// keeps it across reset; [`ErrorCode::StoreBusy`] when the store cannot take it now.
    Save,
}

/// Whether the board is learning the room's light.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum RoomState {
    /// No model.
    Off,
    /// Learning from frames without a detection.
    Learning,
    /// Stopped by the host; what was learnt stays in use.
    Frozen,
}

/// The board's online self-calibration, in [`Status`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct RoomReport {
    /// Learning, frozen or off.
    pub state: RoomState,
    /// Frames learnt from since the model was loaded (or the last reset).
    pub frames: u32,
    /// Updates of the offsets (one per batch of frames).
    pub updates: u32,
    /// The largest offset from the model's predicted face, Q8.8 grey levels.
    pub largest_q88: u16,
    /// Cells whose offset is at the limit.
    pub at_limit: u16,
}

/// Where the running model came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum ModelSource {
    /// No model.
    None,
    /// Built into the firmware image.
    BuiltIn,
    /// Uploaded into RAM: lost at reset.
    Ram,
    /// Uploaded into flash slot `slot` and made current by commit record `seq`: survives reset
    /// and power loss.
    #[allow(missing_docs)]
    Flash { slot: u8, seq: u32 },
}

/// When saved statistics were saved.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct StatsAge {
    /// Board time of the save, ms since that start-up.
    pub saved_ms: u64,
    /// Saved in this start-up (then `saved_ms` is comparable with the board's clock).
    pub this_boot: bool,
    /// The record's sequence number in the store's log.
    pub seq: u32,
}

/// What the board's model store holds (answers [`HostToBoard::GetStore`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct StoreReport {
    /// CRC-32 of the running model blob (as `Status::model_crc`), 0 when none.
    pub model_crc: u32,
    /// Where it came from.
    pub source: ModelSource,
    /// The saved statistics of the running model, if any.
    pub stats: Option<StatsAge>,
    /// Board time now, ms (for the statistics' age).
    pub now_ms: u64,
    /// Flash work pending (a slot or log erase).
    pub busy: bool,
    /// Bytes an upload may take now.
    pub capacity: u32,
}

/// The servo bus's protocol.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum ServoBusKind {
    /// This project's frames ([`BoardToServo`], [`ServoToBoard`]).
    Framed,
    /// Dynamixel Protocol 2.0, the board as bus master.
    Dynamixel,
}

/// One Dynamixel servo's fault counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ServoIdReport {
    /// Dynamixel ID of the servo.
    pub id: u8,
    /// Instructions the servo did not answer in time.
    pub timeouts: u32,
    /// Answers from the wrong ID, of the wrong length, or with an impossible position.
    pub bad_answers: u32,
    /// Statuses with an error number.
    pub errors: u32,
    /// Statuses with the Alert bit.
    pub alerts: u32,
    /// The servo's Hardware Error Status (Dynamixel control table address 70), as last read.
    pub hardware_error: u8,
}

/// The Dynamixel bus as the board sees it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ServoBusReport {
    /// The protocol the board is speaking on the servo bus.
    pub kind: ServoBusKind,
    /// Start-up done, streaming.
    pub running: bool,
    /// Per-joint counters, in joint-map order.
    pub servos: [ServoIdReport; crate::dynamixel::map::MAP_JOINTS],
    /// Packets that failed their CRC or checks on the board's receiver.
    pub rx_errors: u32,
    /// Control periods that found an answer still due.
    pub busy_periods: u32,
}

/// What the board is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Mode {
    /// No valid model yet.
    NoModel,
    /// Watching the face for a mark.
    Observe,
    /// Moving towards the mark.
    Reach,
    /// Holding the reach.
    Hold,
    /// Going back to the home posture.
    Return,
    /// A watchdog tripped: holding still until the link recovers.
    Halted,
    /// A mark is confirmed; the head makes the self gate's probe before any reach.
    SelfTest,
}

/// What the self gate decided about a confirmed mark.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum GateDecision {
    /// The face followed the head: the reach starts.
    Pass,
    /// The face did not follow (another robot, a delayed picture): no reach.
    Reject,
    /// Could not tell: no reach. `Undecided` reasons are [`GateUndecided`].
    Undecided(GateUndecided),
}

/// Why the self gate could not decide.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum GateUndecided {
    /// The probe did not collect its frames in the model's timeout.
    Timeout,
    /// No face frames (face watchdog) or frames without a face in reach of the probe.
    FaceLost,
    /// The servos stopped reporting (servo watchdog, or a bus fault).
    ServosSilent,
    /// The head did not reach a probe pose (a joint limit, a stalled servo).
    HeadStuck,
}

/// One decision of the self gate and its statistic (`firmware::self_gate`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GateReport {
    /// The frame id that decided (or the last one seen).
    pub frame: u16,
    /// Pass, reject, or undecided (and why).
    pub decision: GateDecision,
    /// Measured over expected crop-offset gain (1.0: the robot's own mirror image); NaN when
    /// undecided before both probe poses were seen.
    pub gain_ratio: f32,
    /// Distance of the resting face from the probe's line, pixels (NaN as above).
    pub rest_px: f32,
    /// Largest range of the face's x position over the resting frames and over each probe
    /// pose's frames, pixels (NaN as above): the head holds still then, so does its image.
    pub hold_px: f32,
    /// Largest vertical move of the face at a probe pose from its rest, pixels (NaN as above):
    /// a yaw probe does not move the own image up or down.
    pub level_px: f32,
    /// With a return stage: distance of the face, back at the resting yaw, from the probe's
    /// line, pixels (NaN without one, or as above).
    pub line_px: f32,
    /// With a return stage: probe frames in which the pipeline did not find the face the model
    /// predicts at that head pose (a pass needs none); 0 otherwise.
    pub unlike: u8,
    /// Mean salient pixels of the decoder's prediction error at rest and at the two probe
    /// poses (NaN as above): how well the face matches the one predicted for each head pose.
    pub salient: [f32; 3],
    /// Frames used at the two probe poses.
    pub frames: [u8; 2],
    /// From the mark's confirmation to the decision, ms.
    pub elapsed_ms: u16,
}

/// The winning blob, in full-frame pixels; boxes are inclusive.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BlobReport {
    /// Pixels in the blob.
    pub area: u32,
    /// Bounding box `[x0, y0, x1, y1]`, inclusive, in full-frame pixels.
    pub box_xyxy: [u16; 4],
    /// Centre of mass `[x, y]` in full-frame pixels (sub-pixel).
    pub centroid: [f32; 2],
}

/// The board's answer to one face frame.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Detection {
    /// The id of the face frame this answers.
    pub frame: u16,
    /// The head angles (HeadYaw, HeadPitch) the servos reported, which the decoder used.
    pub head: [f32; 2],
    /// The winning blob, or `None` when no mark was seen.
    pub blob: Option<BlobReport>,
    /// The confirmation filter passed on this frame and a reach starts.
    pub confirmed: bool,
    /// Reach targets for [`crate::joints::REACH_JOINTS`], after clamping.
    pub reach: Option<[f32; 5]>,
    /// Why this frame could give no detection whatever it showed (`None`: the face was seen).
    pub reason: Option<NoDetection>,
}

/// Why a frame yields no detection and no reach: the photometric fit of the face crop to the
/// predicted face refused it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum NoDetection {
    /// The crop does not follow the predicted face: black, white, covered, an empty room.
    NoFace,
    /// The light is outside what the fit explains, or changed while the frame was taken.
    SceneChanged,
}

/// Counters and state, sent on request and when something goes wrong.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Status {
    /// What the board is doing now.
    pub mode: Mode,
    /// CRC-32 of the running model blob, 0 when none.
    pub model_crc: u32,
    /// Face frames received whole (their CRC-32 matched).
    pub frames: u32,
    /// Frames on which a blob was found.
    pub detections: u32,
    /// Reaches started.
    pub reaches: u32,
    /// What the board's receiver saw on the host link.
    pub host_link: crate::frame::LinkCounters,
    /// What the board's receiver saw on the servo link.
    pub servo_link: crate::frame::LinkCounters,
    /// Times no face frame came within the face watchdog's period.
    pub face_watchdog_trips: u32,
    /// Times no servo state came within the servo watchdog's period.
    pub servo_watchdog_trips: u32,
    /// Targets that were outside the limits and were clamped or dropped before sending.
    pub clamped_targets: u32,
    /// Face frames dropped unfinished because a newer one started.
    pub frames_superseded: u32,
    /// Face chunks that arrived twice, or for a frame not in progress.
    pub chunks_ignored: u32,
    /// Reassembled images whose CRC-32 did not match (all chunks asked for again).
    pub frame_crc_errors: u32,
    /// Frames refused as [`NoDetection::NoFace`].
    pub no_face: u32,
    /// Frames refused as [`NoDetection::SceneChanged`].
    pub scene_changed: u32,
    /// What the board has learnt of the room's light.
    pub room: RoomReport,
}

/// Why the board refused something.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum ErrorCode {
    /// A frame chunk for another frame, past the end, or a crop of the wrong size.
    BadFrame,
    /// A model upload chunk out of order, too large, or a commit without a begin.
    BadUpload,
    /// The uploaded blob failed validation; `detail` is the [`crate::blob::BlobError`] code.
    BadModel,
    /// A configuration value out of range.
    BadConfig,
    /// No face frame for the face watchdog's period: holding still.
    FaceTimeout,
    /// No servo state for the servo watchdog's period: motion stopped.
    ServoTimeout,
    /// A frame arrived but no model is loaded.
    NoModel,
    /// A frame of another protocol version arrived; `detail` is its version.
    Version,
    /// Dynamixel start-up: no answer to Ping; `detail` is the ID. Nothing moves.
    ServoMissing,
    /// A Dynamixel servo refused a start-up step or raised its Alert: `detail` is the ID, its
    /// Hardware Error Status << 8 and the status's error byte << 16. Motion stops.
    ServoFault,
    /// A Dynamixel servo stopped answering; `detail` is the ID.
    ServoLost,
    /// A joint map was refused; `detail` is the index of the joint at fault.
    BadServoMap,
    /// A [`HostToBoard::MoveHead`] was refused: `detail` 0 an angle outside the joint's limits
    /// or not finite, 1 no servo positions yet (or the servo watchdog holds), 2 a reach in
    /// progress.
    HeadRefused,
    /// The head did not hold still within eight encoder counts of the asked pose in time;
    /// `detail` is the milliseconds waited.
    HeadNotSettled,
    /// The model store is busy with flash work: `detail` 0 statistics not reset (a log
    /// compaction runs; ask again), 1 a frame not read (a sector of the model's flash bank is
    /// being erased).
    StoreBusy,
}

/// Board to host.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum BoardToHost {
    /// Answers [`HostToBoard::Ping`] with its `nonce`.
    #[allow(missing_docs)]
    Pong { nonce: u32 },
    /// Answers [`HostToBoard::GetStatus`], and is sent when something goes wrong.
    Status(Status),
    /// The answer to a whole face frame; while the arm is up, the one that started the reach again.
    Detection(Detection),
    /// The uploaded model passed validation and runs now.
    /// `crc32` is the CRC-32 of the blob now running.
    #[allow(missing_docs)]
    ModelAccepted { crc32: u32 },
    /// Something was refused or went wrong; `detail` depends on `code` (see [`ErrorCode`]).
    #[allow(missing_docs)]
    Error { code: ErrorCode, detail: u32 },
    /// Where a face frame stands: after its last chunk, on completion, or in answer to a `FramePoll`.
    FrameAck(FrameAck),
    /// The model upload byte offset the board wants next.
    /// `next` is a byte offset into the blob.
    #[allow(missing_docs)]
    UploadAck { next: u32 },
    /// Answers [`HostToBoard::GetServoBus`].
    ServoBus(ServoBusReport),
    /// A decision of the self gate (protocol 3; hold and level 4), sent once per probe.
    SelfGate(GateReport),
    /// The head settled after [`HostToBoard::MoveHead`]: (HeadYaw, HeadPitch) as the servos
    /// report them, radians.
    #[allow(missing_docs)]
    HeadAt { head: [f32; 2] },
    /// Answers [`HostToBoard::GetStore`] and [`HostToBoard::ResetStats`].
    Store(StoreReport),
}

/// One joint's commanded position.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct JointTarget {
    /// Which joint.
    pub joint: Joint,
    /// Radians; the sender guarantees it is inside the joint's limits.
    pub position: f32,
}

/// Fault flags a servo reports, as bits of [`JointState::faults`].
pub mod fault {
    /// A target outside the joint limits arrived and was refused.
    pub const LIMIT: u8 = 1 << 0;
    /// The servo is not following its target.
    pub const STALL: u8 = 1 << 1;
    /// The servo is overheating.
    pub const OVERHEAT: u8 = 1 << 2;
    /// No target for the servo's hold timeout: holding position.
    pub const TIMEOUT: u8 = 1 << 3;
}

/// One joint's reported state.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct JointState {
    /// Which joint.
    pub joint: Joint,
    /// Measured position in radians (encoder-quantised).
    pub position: f32,
    /// Whether the servo's torque is on (it holds its position).
    pub stiffness: bool,
    /// Fault bits, see [`fault`].
    pub faults: u8,
}

/// Board to servos.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum BoardToServo {
    /// Position targets, sent every control period while moving or holding.
    Targets {
        /// Board time in ms when the targets were sent (wraps after about 49 days).
        time_ms: u32,
        /// One target per joint to move; at most [`MAX_BUS_JOINTS`].
        targets: heapless::Vec<JointTarget, MAX_BUS_JOINTS>,
    },
    /// Asks every servo on the bus for its state.
    StateRequest,
    /// Turns every servo's torque on (`on: true`: they hold where they are) or off.
    #[allow(missing_docs)]
    Stiffness { on: bool },
}

/// Servos to board.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum ServoToBoard {
    /// Every joint's state, sent periodically and in answer to [`BoardToServo::StateRequest`].
    States {
        /// Servo time in ms when the states were measured.
        time_ms: u32,
        /// One state per joint on the bus; at most [`MAX_BUS_JOINTS`].
        states: heapless::Vec<JointState, MAX_BUS_JOINTS>,
    },
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::{encode_message, FrameAccumulator, MAX_PAYLOAD, MAX_WIRE_FRAME};
    use proptest::prelude::*;

    fn round_trip<'a, T>(msg: &T, buf: &'a mut [u8]) -> T
    where
        T: Serialize + Deserialize<'a> + core::fmt::Debug + PartialEq,
    {
        let used = postcard::to_slice(msg, buf).unwrap().len();
        assert!(used <= MAX_PAYLOAD, "{msg:?} takes {used} bytes");
        postcard::from_bytes(&buf[..used]).unwrap()
    }

    #[test]
    fn literal_payloads() {
        // Variant index then fields, as postcard varints.
        let ping = HostToBoard::Ping { nonce: 300 };
        assert_eq!(
            postcard::to_slice(&ping, &mut [0u8; 8]).unwrap(),
            &[0x00, 0xAC, 0x02]
        );
        assert_eq!(
            postcard::from_bytes::<HostToBoard>(&[0x07]).unwrap(),
            HostToBoard::GetStatus
        );
        let chunk = HostToBoard::FrameChunk { frame: 1, offset: 2, data: &[9, 8] };
        assert_eq!(
            postcard::to_slice(&chunk, &mut [0u8; 8]).unwrap(),
            &[0x02, 0x01, 0x02, 0x02, 9, 8]
        );
        // A joint target: variant 0, time 10, one target LElbowRoll (id 5) at 0.0 rad.
        let mut targets = heapless::Vec::new();
        targets.push(JointTarget { joint: Joint::LElbowRoll, position: 0.0 }).unwrap();
        let t = BoardToServo::Targets { time_ms: 10, targets };
        assert_eq!(
            postcard::to_slice(&t, &mut [0u8; 16]).unwrap(),
            &[0x00, 0x0A, 0x01, 0x05, 0, 0, 0, 0]
        );
        // An unknown joint id does not parse.
        assert!(postcard::from_bytes::<BoardToServo>(&[0x00, 0x0A, 0x01, 0x63, 0, 0, 0, 0]).is_err());
        // Unknown variant.
        assert!(postcard::from_bytes::<HostToBoard>(&[0x7F]).is_err());
    }

    #[test]
    fn largest_messages_fit_a_frame() {
        let data = [0xEEu8; CHUNK];
        let mut buf = [0u8; MAX_PAYLOAD];
        round_trip(&HostToBoard::FrameChunk { frame: u16::MAX, offset: u16::MAX, data: &data }, &mut buf);
        let mut buf = [0u8; MAX_PAYLOAD];
        round_trip(&HostToBoard::ModelChunk { offset: u32::MAX, data: &data }, &mut buf);
        let mut states = heapless::Vec::new();
        for j in Joint::ALL.iter().take(MAX_BUS_JOINTS) {
            states
                .push(JointState { joint: *j, position: -1.5, stiffness: true, faults: 0xFF })
                .unwrap();
        }
        let mut buf = [0u8; MAX_PAYLOAD];
        round_trip(&ServoToBoard::States { time_ms: u32::MAX, states }, &mut buf);
        let big = crate::frame::LinkCounters {
            frames: u32::MAX,
            crc_errors: u32::MAX,
            cobs_errors: u32::MAX,
            oversized: u32::MAX,
            malformed: u32::MAX,
            seq_gaps: u32::MAX,
        };
        let status = Status {
            mode: Mode::Halted,
            model_crc: u32::MAX,
            frames: u32::MAX,
            detections: u32::MAX,
            reaches: u32::MAX,
            host_link: big,
            servo_link: big,
            face_watchdog_trips: u32::MAX,
            servo_watchdog_trips: u32::MAX,
            clamped_targets: u32::MAX,
            frames_superseded: u32::MAX,
            chunks_ignored: u32::MAX,
            frame_crc_errors: u32::MAX,
            no_face: u32::MAX,
            scene_changed: u32::MAX,
            room: RoomReport {
                state: RoomState::Frozen,
                frames: u32::MAX,
                updates: u32::MAX,
                largest_q88: u16::MAX,
                at_limit: u16::MAX,
            },
        };
        let mut buf = [0u8; MAX_PAYLOAD];
        round_trip(&BoardToHost::Status(status), &mut buf);
        let all = ChunkSet::first(MAX_FRAME_CHUNKS);
        let ack = FrameAck { frame: u16::MAX, round: u8::MAX, state: FrameState::Missing(all) };
        let mut buf = [0u8; MAX_PAYLOAD];
        round_trip(&BoardToHost::FrameAck(ack), &mut buf);
        let header = FrameHeader {
            frame: u16::MAX,
            crop_x: u16::MAX,
            crop_y: u16::MAX,
            crop_sub: [i8::MIN; 2],
            width: u16::MAX,
            height: u16::MAX,
            chunk: u16::MAX,
            crc32: u32::MAX,
        };
        let mut buf = [0u8; MAX_PAYLOAD];
        round_trip(&HostToBoard::FramePoll { header, round: u8::MAX }, &mut buf);
    }

    #[test]
    fn framed_message_round_trip() {
        let msg = HostToBoard::ModelChunk { offset: 4096, data: &[1, 0, 2, 0, 3] };
        let mut wire = [0u8; MAX_WIRE_FRAME];
        let n = encode_message(77, &msg, &mut wire).unwrap();
        let mut acc = FrameAccumulator::<MAX_WIRE_FRAME>::new();
        let mut got = None;
        for &b in &wire[..n] {
            if let Some(r) = acc.push(b) {
                let f = r.unwrap();
                assert_eq!(f.seq, 77);
                got = Some(f.message::<HostToBoard>().map(|m| format!("{m:?}")));
            }
        }
        assert_eq!(got, Some(Ok(format!("{msg:?}"))));
    }

    #[test]
    fn frame_ack_literal() {
        // Variant 5 (FrameAck), frame 3, round 1, state 1 (Missing), then the bitmap's length
        // and bytes up to the last non-zero one: chunks 0 and 9 missing.
        let mut m = ChunkSet::EMPTY;
        m.insert(0);
        m.insert(9);
        let ack = BoardToHost::FrameAck(FrameAck { frame: 3, round: 1, state: FrameState::Missing(m) });
        assert_eq!(
            postcard::to_slice(&ack, &mut [0u8; 64]).unwrap(),
            &[0x05, 0x03, 0x01, 0x01, 0x02, 0x01, 0x02]
        );
        let back: BoardToHost = postcard::from_bytes(&[0x05, 0x03, 0x01, 0x01, 0x02, 0x01, 0x02]).unwrap();
        assert_eq!(back, ack);
        // A bitmap longer than 32 bytes does not parse.
        let mut long = vec![0x05, 0x03, 0x01, 0x01, 33];
        long.extend([0xFF; 33]);
        assert!(postcard::from_bytes::<BoardToHost>(&long).is_err());
        let done = BoardToHost::FrameAck(FrameAck { frame: 3, round: 0, state: FrameState::Complete });
        assert_eq!(postcard::to_slice(&done, &mut [0u8; 8]).unwrap(), &[0x05, 0x03, 0x00, 0x00]);
        assert_eq!(
            postcard::to_slice(&BoardToHost::UploadAck { next: 300 }, &mut [0u8; 8]).unwrap(),
            &[0x06, 0xAC, 0x02]
        );
    }

    #[test]
    fn frame_start_literal_with_the_sub_pixel_crop() {
        // Variant 1 (FrameStart): frame 3, crop (140, 95) as varints, crop_sub (-5, 32) as two
        // raw bytes (postcard writes an i8 as one two's-complement byte), 75 x 58, chunk 224,
        // CRC-32 1.
        let h = FrameHeader { frame: 3, crop_x: 140, crop_y: 95, crop_sub: [-5, 32], width: 75, height: 58, chunk: 224, crc32: 1 };
        let bytes = [0x01, 0x03, 0x8C, 0x01, 0x5F, 0xFB, 0x20, 0x4B, 0x3A, 0xE0, 0x01, 0x01];
        assert_eq!(postcard::to_slice(&HostToBoard::FrameStart(h), &mut [0u8; 32]).unwrap(), &bytes);
        assert_eq!(postcard::from_bytes::<HostToBoard>(&bytes).unwrap(), HostToBoard::FrameStart(h));
        assert!(h.is_valid());
        assert_eq!(h.position(), [140.0 - 5.0 / 64.0, 95.5]);
        // Past a pixel either way: it parses, and is refused as invalid.
        for (i, b) in [(5, 0x41u8), (5, 0xBF), (6, 0x80), (6, 0x7F)] {
            let mut bad = bytes;
            bad[i] = b;
            let Ok(HostToBoard::FrameStart(g)) = postcard::from_bytes::<HostToBoard>(&bad) else { panic!("{bad:?}") };
            assert!(!g.is_valid(), "{:?}", g.crop_sub);
        }
        let mut edge = bytes;
        (edge[5], edge[6]) = (0xC0, 0x40);
        let Ok(HostToBoard::FrameStart(g)) = postcard::from_bytes::<HostToBoard>(&edge) else { panic!() };
        assert!(g.is_valid(), "exactly a pixel either way");
        assert_eq!(g.position(), [139.0, 96.0]);
        // A version-3 header (no crop_sub) is cut short: its bytes do not parse as one.
        let old = [0x01, 0x03, 0x8C, 0x01, 0x5F, 0x4B, 0x3A, 0xE0, 0x01, 0x01];
        assert!(postcard::from_bytes::<HostToBoard>(&old).is_err());
    }

    #[test]
    fn crop_sub_rounds_and_clamps() {
        assert_eq!(crop_sub(0.0), 0);
        assert_eq!(crop_sub(0.25), 16);
        assert_eq!(crop_sub(-0.25), -16);
        assert_eq!(crop_sub(1.0 / 128.0), 1, "half a step rounds away from zero");
        assert_eq!(crop_sub(-1.0 / 128.0), -1);
        assert_eq!(crop_sub(0.5), 32);
        assert_eq!(crop_sub(1.0), SUB_MAX);
        assert_eq!(crop_sub(1.9), SUB_MAX);
        assert_eq!(crop_sub(-7.0), -SUB_MAX);
        assert_eq!(crop_sub(f32::NAN), 0);
        assert_eq!(crop_sub(f32::INFINITY), 0);
        assert_eq!(CropAt::subpixel([3, 4], [0.5, -0.125]), CropAt { px: [3, 4], sub: [32, -8] });
        assert_eq!(CropAt::from([3, 4]).sub, [0, 0]);
    }

    #[test]
    fn chunk_geometry() {
        let h = FrameHeader { frame: 1, crop_x: 0, crop_y: 0, crop_sub: [0; 2], width: 58, height: 75, chunk: 224, crc32: 0 };
        assert_eq!(h.pixels(), 4350);
        assert_eq!(h.chunks(), 20);
        assert_eq!(h.chunk_range(19), 4256..4350);
        assert_eq!(h.chunk_range(20), 4350..4350);
        assert!(h.is_valid());
        assert!(!FrameHeader { chunk: MIN_CHUNK as u16 - 1, ..h }.is_valid());
        assert!(!FrameHeader { chunk: CHUNK as u16 + 1, ..h }.is_valid());
        // 96 x 64 in chunks of 24 is exactly 256 chunks; one pixel more is too many.
        assert!(FrameHeader { width: 96, height: 64, chunk: 24, ..h }.is_valid());
        assert!(!FrameHeader { width: 97, height: 64, chunk: 24, ..h }.is_valid());
        assert!(!FrameHeader { chunk: 0, ..h }.is_valid());
        assert!(is_older(5, 6) && is_older(u16::MAX, 0) && !is_older(6, 6) && !is_older(7, 6));
        assert!(!is_older(6u16.wrapping_sub(STALE_WINDOW), 6), "a restarted host is not stale");
    }

    #[test]
    fn chunk_set() {
        let mut s = ChunkSet::first(20);
        assert_eq!(s.len(), 20);
        assert!(s.remove(3) && !s.remove(3));
        assert_eq!(s.iter().take(4).collect::<Vec<_>>(), vec![0, 1, 2, 4]);
        assert_eq!(s.first_member(), Some(0));
        let mut t = ChunkSet::EMPTY;
        t.insert(203);
        assert_eq!(t.first_member(), Some(203));
        assert_eq!(ChunkSet::EMPTY.first_member(), None);
        s.insert(MAX_FRAME_CHUNKS); // out of range: ignored
        assert_eq!(s.len(), 19);
        assert!(ChunkSet::EMPTY.is_empty() && !s.is_empty());
        assert_eq!(ChunkSet::first(MAX_FRAME_CHUNKS + 5).len(), MAX_FRAME_CHUNKS);
    }

    #[test]
    fn trailing_bytes_are_malformed() {
        let f = crate::frame::Frame { seq: 0, payload: &[0x07, 0x00] };
        assert!(f.message::<HostToBoard>().is_err());
    }

    fn arb_detection() -> impl Strategy<Value = Detection> {
        (
            any::<u16>(),
            any::<[f32; 2]>(),
            proptest::option::of((any::<u32>(), any::<[u16; 4]>(), any::<[f32; 2]>())),
            any::<bool>(),
            proptest::option::of(any::<[f32; 5]>()),
            proptest::option::of(any::<bool>()),
        )
            .prop_map(|(frame, head, blob, confirmed, reach, reason)| Detection {
                frame,
                head,
                blob: blob.map(|(area, box_xyxy, centroid)| BlobReport { area, box_xyxy, centroid }),
                confirmed,
                reach,
                reason: reason.map(|r| if r { NoDetection::NoFace } else { NoDetection::SceneChanged }),
            })
    }

    proptest! {
        #[test]
        fn detection_round_trips(d in arb_detection()) {
            let msg = BoardToHost::Detection(d);
            let mut buf = [0u8; MAX_PAYLOAD];
            let used = postcard::to_slice(&msg, &mut buf).unwrap().len();
            let back: BoardToHost = postcard::from_bytes(&buf[..used]).unwrap();
            // Compare bit patterns so that NaN round trips count.
            prop_assert_eq!(format!("{:?}", back), format!("{:?}", msg));
        }

        #[test]
        fn config_round_trips(threshold: f32, k: u8, n: u8, area: u16, speed: f32, hold: u32, var: bool, two: bool) {
            let c = Config {
                threshold,
                normalisation: if var { Normalisation::Variance } else { Normalisation::StdDev },
                sided: if two { Sided::Two } else { Sided::One },
                min_area: area, confirm_k: k, confirm_n: n, speed_fraction: speed, hold_ms: hold,
            };
            let mut buf = [0u8; MAX_PAYLOAD];
            let back = round_trip(&HostToBoard::Configure(c), &mut buf);
            prop_assert_eq!(format!("{:?}", back), format!("{:?}", HostToBoard::Configure(c)));
        }

        #[test]
        fn random_payloads_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
            let _ = postcard::from_bytes::<HostToBoard>(&bytes);
            let _ = postcard::from_bytes::<BoardToHost>(&bytes);
            let _ = postcard::from_bytes::<BoardToServo>(&bytes);
            let _ = postcard::from_bytes::<ServoToBoard>(&bytes);
        }
    }
}

#[cfg(test)]
mod servo_bus_tests {
    use super::*;
    use crate::dynamixel::map::default_map;
    use crate::frame::MAX_PAYLOAD;

    #[test]
    fn servo_bus_messages_fit_a_frame_and_round_trip() {
        let mut buf = [0u8; MAX_PAYLOAD];
        let mut map = default_map();
        for e in &mut map {
            (e.zero, e.raw_min, e.raw_max, e.counts_per_rad) = (i32::MIN, i32::MIN, i32::MAX, f32::MAX);
        }
        let msg = HostToBoard::SetServoMap(map);
        let n = postcard::to_slice(&msg, &mut buf).unwrap().len();
        assert_eq!(postcard::from_bytes::<HostToBoard>(&buf[..n]).unwrap(), msg);
        let big = ServoIdReport {
            id: 0xFC,
            timeouts: u32::MAX,
            bad_answers: u32::MAX,
            errors: u32::MAX,
            alerts: u32::MAX,
            hardware_error: 0xFF,
        };
        let r = BoardToHost::ServoBus(ServoBusReport {
            kind: ServoBusKind::Dynamixel,
            running: true,
            servos: [big; 5],
            rx_errors: u32::MAX,
            busy_periods: u32::MAX,
        });
        let n = postcard::to_slice(&r, &mut buf).unwrap().len();
        assert_eq!(postcard::from_bytes::<BoardToHost>(&buf[..n]).unwrap(), r);
    }
}
