//! Arbitrary bytes into the frame accumulator and every message type: no panic, and every frame it
//! accepts re-encodes to a frame that checks again.
#![no_main]
use libfuzzer_sys::fuzz_target;
use msr_shared::frame::{encode_payload, FrameAccumulator, MAX_WIRE_FRAME};
use msr_shared::msg::{BoardToHost, BoardToServo, HostToBoard, ServoToBoard};

fuzz_target!(|data: &[u8]| {
    let mut acc = FrameAccumulator::<MAX_WIRE_FRAME>::new();
    for &b in data {
        if let Some(Ok(frame)) = acc.push(b) {
            let _ = frame.message::<HostToBoard>();
            let _ = frame.message::<BoardToHost>();
            let _ = frame.message::<BoardToServo>();
            let _ = frame.message::<ServoToBoard>();
            let (seq, payload) = (frame.seq, frame.payload.to_vec());
            let mut wire = [0u8; MAX_WIRE_FRAME];
            let n = encode_payload(seq, &payload, &mut wire).expect("an accepted payload fits");
            let mut again = FrameAccumulator::<MAX_WIRE_FRAME>::new();
            let got = wire[..n].iter().find_map(|&b| again.push(b).map(|r| r.map(|f| f.payload.to_vec())));
            assert_eq!(got, Some(Ok(payload)));
        }
    }
});
