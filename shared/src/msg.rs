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
//! Bounds. Board: one image buffer ([`MAX_FRAME_BYTES`] = 9216 bytes: the largest grey face,
//! 6144 bytes, and its chroma planes), one [`FrameHeader`], one
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

mod face;
mod servo;

use crate::blob::{Normalisation, Sided};
use serde::{Deserialize, Serialize};

pub use face::{
    crop_sub, is_older, ChunkSet, CropAt, FrameAck, FrameHeader, FrameState, BITMAP_BYTES, CHUNK,
    MAX_FRAME_BYTES, MAX_FRAME_CHUNKS, MIN_CHUNK, STALE_WINDOW, SUB_MAX, SUB_PER_PX,
};
pub use servo::{fault, BoardToServo, JointState, JointTarget, ServoToBoard, MAX_BUS_JOINTS};

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

#[cfg(test)]
mod tests;
