use super::*;
use crate::joints::Joint;
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
        colour: true,
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
    // CRC-32 1, grey only (a bool is one byte, 0 or 1).
    let h = FrameHeader { frame: 3, crop_x: 140, crop_y: 95, crop_sub: [-5, 32], width: 75, height: 58, chunk: 224, crc32: 1, colour: false };
    let bytes = [0x01, 0x03, 0x8C, 0x01, 0x5F, 0xFB, 0x20, 0x4B, 0x3A, 0xE0, 0x01, 0x01, 0x00];
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
    let h = FrameHeader { frame: 1, crop_x: 0, crop_y: 0, crop_sub: [0; 2], width: 58, height: 75, chunk: 224, crc32: 0, colour: false };
    assert_eq!(h.pixels(), 4350);
    assert_eq!(h.chunks(), 20);
    assert_eq!(h.chunk_range(19), 4256..4350);
    assert_eq!(h.chunk_range(20), 4350..4350);
    assert!(h.is_valid());
    // With its chroma planes: 38 x 29 blocks, two planes after the grey.
    let c = FrameHeader { colour: true, ..h };
    assert_eq!((c.pixels(), c.bytes(), c.chunks()), (4350, 4350 + 2 * 1102, 30));
    assert_eq!(c.chunk_range(29), 6496..6554);
    // The largest face in colour needs chunks of 36 to stay within 256 of them.
    assert!(!FrameHeader { width: 96, height: 64, chunk: 24, ..c }.is_valid());
    assert!(FrameHeader { width: 96, height: 64, chunk: 36, ..c }.is_valid());
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
