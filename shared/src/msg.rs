//! Messages of the two serial links. Each is one postcard payload inside one [`crate::frame`].
//!
//! - Host link (a PC or the sim, to the board): [`HostToBoard`] and [`BoardToHost`].
//! - Servo bus (the board, to the joint servos): [`BoardToServo`] and [`ServoToBoard`].
//!
//! Large things (a face image, a model blob) travel in chunks of at most [`CHUNK`] bytes so that
//! every frame stays below [`crate::frame::MAX_PAYLOAD`] and a damaged frame costs one chunk.

use crate::blob::{Normalisation, Sided};
use crate::joints::Joint;
use serde::{Deserialize, Serialize};

/// Largest data chunk in a frame or model chunk message.
pub const CHUNK: usize = 224;
/// Most joints in one servo-bus message: head and both arms.
pub const MAX_BUS_JOINTS: usize = 14;

/// Announces a face image; its pixels follow in [`HostToBoard::FrameChunk`]s.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FrameHeader {
    /// Frame number chosen by the host; chunks name it.
    pub frame: u16,
    /// Where the face crop sits in the full camera frame (pixels), for full-frame reports and
    /// the reach network's input; the nearest whole pixel when the host cropped at sub-pixel
    /// precision (`blob::CropMode::Subpixel`), so within half a pixel.
    pub crop_x: u16,
    pub crop_y: u16,
    /// Crop size; must equal the model's face size.
    pub width: u16,
    pub height: u16,
}

/// Run-time settings the host may change. Out-of-range values are refused by the board.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Config {
    /// Saliency threshold in units of the normalisation (sigma or sigma^2).
    pub threshold: f32,
    pub normalisation: Normalisation,
    pub sided: Sided,
    /// Smallest blob, in pixels, that counts as a mark.
    pub min_area: u16,
    /// A mark must be seen in `confirm_k` of the last `confirm_n` frames before a reach.
    pub confirm_k: u8,
    pub confirm_n: u8,
    /// Fraction of each joint's maximum velocity used when moving.
    pub speed_fraction: f32,
    /// How long a reach is held before returning home.
    pub hold_ms: u32,
}

/// Host to board.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum HostToBoard<'a> {
    Ping {
        nonce: u32,
    },
    FrameStart(FrameHeader),
    FrameChunk {
        frame: u16,
        /// Byte offset of `data` in the row-major grey image.
        offset: u16,
        #[serde(borrow)]
        data: &'a [u8],
    },
    /// Starts a model upload of `len` bytes whose CRC-32 (ISO-HDLC) is `crc32`.
    ModelBegin {
        len: u32,
        crc32: u32,
    },
    ModelChunk {
        offset: u32,
        #[serde(borrow)]
        data: &'a [u8],
    },
    /// Validates the uploaded blob and switches to it; the old model stays if it is bad.
    ModelCommit,
    Configure(Config),
    GetStatus,
    /// Chooses the servo bus protocol; the Dynamixel master starts up anew.
    UseServoBus(ServoBusKind),
    /// A new Dynamixel joint map (refused as a whole with [`ErrorCode::BadServoMap`]); the
    /// servo bus then speaks Dynamixel, and its start-up runs again.
    SetServoMap([crate::dynamixel::map::JointMapEntry; crate::dynamixel::map::MAP_JOINTS]),
    /// Asks for [`BoardToHost::ServoBus`].
    GetServoBus,
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
    pub id: u8,
    pub timeouts: u32,
    /// Answers from the wrong ID, of the wrong length, or with an impossible position.
    pub bad_answers: u32,
    /// Statuses with an error number.
    pub errors: u32,
    /// Statuses with the Alert bit.
    pub alerts: u32,
    pub hardware_error: u8,
}

/// The Dynamixel bus as the board sees it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ServoBusReport {
    pub kind: ServoBusKind,
    /// Start-up done, streaming.
    pub running: bool,
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
}

/// The winning blob, in full-frame pixels; boxes are inclusive.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BlobReport {
    pub area: u32,
    pub box_xyxy: [u16; 4],
    pub centroid: [f32; 2],
}

/// The board's answer to one face frame.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Detection {
    pub frame: u16,
    /// The head angles (HeadYaw, HeadPitch) the servos reported, which the decoder used.
    pub head: [f32; 2],
    pub blob: Option<BlobReport>,
    /// The confirmation filter passed on this frame and a reach starts.
    pub confirmed: bool,
    /// Reach targets for [`crate::joints::REACH_JOINTS`], after clamping.
    pub reach: Option<[f32; 5]>,
}

/// Counters and state, sent on request and when something goes wrong.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Status {
    pub mode: Mode,
    /// CRC-32 of the running model blob, 0 when none.
    pub model_crc: u32,
    pub frames: u32,
    pub detections: u32,
    pub reaches: u32,
    pub host_link: crate::frame::LinkCounters,
    pub servo_link: crate::frame::LinkCounters,
    pub face_watchdog_trips: u32,
    pub servo_watchdog_trips: u32,
    /// Targets that were outside the limits and were clamped or dropped before sending.
    pub clamped_targets: u32,
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
    /// Dynamixel start-up: no answer to Ping; `detail` is the ID. Nothing moves.
    ServoMissing,
    /// A Dynamixel servo refused a start-up step or raised its Alert: `detail` is the ID, its
    /// Hardware Error Status << 8 and the status's error byte << 16. Motion stops.
    ServoFault,
    /// A Dynamixel servo stopped answering; `detail` is the ID.
    ServoLost,
    /// A joint map was refused; `detail` is the index of the joint at fault.
    BadServoMap,
}

/// Board to host.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum BoardToHost {
    Pong { nonce: u32 },
    Status(Status),
    Detection(Detection),
    /// The uploaded model passed validation and runs now.
    ModelAccepted { crc32: u32 },
    Error { code: ErrorCode, detail: u32 },
    ServoBus(ServoBusReport),
}

/// One joint's commanded position.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct JointTarget {
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
    pub const OVERHEAT: u8 = 1 << 2;
    /// No target for the servo's hold timeout: holding position.
    pub const TIMEOUT: u8 = 1 << 3;
}

/// One joint's reported state.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct JointState {
    pub joint: Joint,
    /// Measured position in radians (encoder-quantised).
    pub position: f32,
    pub stiffness: bool,
    pub faults: u8,
}

/// Board to servos.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum BoardToServo {
    /// Position targets, sent every control period while moving or holding.
    Targets {
        time_ms: u32,
        targets: heapless::Vec<JointTarget, MAX_BUS_JOINTS>,
    },
    /// Asks every servo on the bus for its state.
    StateRequest,
    Stiffness { on: bool },
}

/// Servos to board.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum ServoToBoard {
    States {
        time_ms: u32,
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
        };
        let mut buf = [0u8; MAX_PAYLOAD];
        round_trip(&BoardToHost::Status(status), &mut buf);
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
        )
            .prop_map(|(frame, head, blob, confirmed, reach)| Detection {
                frame,
                head,
                blob: blob.map(|(area, box_xyxy, centroid)| BlobReport { area, box_xyxy, centroid }),
                confirmed,
                reach,
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
