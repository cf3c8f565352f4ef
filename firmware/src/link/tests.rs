//! Face-frame reassembly against a hostile line: the host's [`FaceSender`] and the board's
//! [`Assembly`] talk through wire frames that are lost, duplicated, reordered and corrupted.

use super::*;
use msr_shared::deliver::{face_header, FaceSender};
use msr_shared::frame::{encode_message_vec, Sequencer};
use msr_shared::msg::{BoardToHost, HostToBoard, MIN_CHUNK};
use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::HashMap;

/// How the line misbehaves, per wire frame (probabilities in percent).
#[derive(Clone, Copy, Debug)]
struct Line {
    loss: u32,
    dup: u32,
    /// Swapped with a later frame of the same batch.
    reorder: u32,
    /// A bit flipped on the wire (the CRC-16 catches it).
    flip: u32,
    /// A chunk's data changed *and* its frame re-checksummed: what a CRC-16 miss looks like.
    /// Only the image's CRC-32 stands between it and the pipeline.
    forge: u32,
}

fn line() -> impl Strategy<Value = Line> {
    (0u32..40, 0u32..30, 0u32..30, 0u32..30, 0u32..5)
        .prop_map(|(loss, dup, reorder, flip, forge)| Line { loss, dup, reorder, flip, forge })
}

/// Passes a batch of wire frames through the line.
fn transmit(batch: Vec<Vec<u8>>, line: Line, rng: &mut ChaCha8Rng) -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    for w in batch {
        if rng.gen_range(0..100) < line.loss {
            continue;
        }
        let copies = if rng.gen_range(0..100) < line.dup { 2 } else { 1 };
        for _ in 0..copies {
            let mut w = w.clone();
            if rng.gen_range(0..100) < line.flip {
                let i = rng.gen_range(0..w.len());
                w[i] ^= 1 << rng.gen_range(0..8);
            }
            out.push(w);
        }
    }
    for i in 0..out.len() {
        if rng.gen_range(0..100) < line.reorder {
            let j = rng.gen_range(i..out.len());
            out.swap(i, j);
        }
    }
    out
}

/// The host's message, with its data forged (re-encoded, so its CRC-16 is valid) sometimes.
fn encode(msg: &HostToBoard, seq: &mut Sequencer, line: Line, rng: &mut ChaCha8Rng) -> Vec<u8> {
    if let HostToBoard::FrameChunk { frame, offset, data } = msg {
        if rng.gen_range(0..100) < line.forge && !data.is_empty() {
            let mut bad = data.to_vec();
            let i = rng.gen_range(0..bad.len());
            bad[i] ^= 1 << rng.gen_range(0..8);
            let forged = HostToBoard::FrameChunk { frame: *frame, offset: *offset, data: &bad };
            return encode_message_vec(seq.next(), &forged).unwrap();
        }
    }
    encode_message_vec(seq.next(), msg).unwrap()
}

/// The board's side: wire frames in, acks out, every completed image recorded.
struct BoardSide {
    rx: Rx,
    asm: Box<Assembly>,
    size: [u16; 2],
    completed: Vec<(u16, Vec<u8>)>,
}

impl BoardSide {
    fn take(&mut self, wire: &[u8], seq: &mut Sequencer) -> Vec<Vec<u8>> {
        let mut replies = Vec::new();
        for &b in wire {
            let Some(Ok(f)) = self.rx.push(b) else { continue };
            let Ok(msg) = f.message::<HostToBoard>() else { continue };
            let [w, h] = self.size;
            let ack = match msg {
                HostToBoard::FrameStart(hd) => {
                    let _ = self.asm.start(hd, w, h);
                    None
                }
                HostToBoard::FrameChunk { frame, offset, data } => match self.asm.chunk(frame, offset, data) {
                    Ok(Progress::Ack(a)) => Some(a),
                    Ok(Progress::Complete(hd)) => {
                        self.completed.push((hd.frame, self.asm.pixels(&hd).to_vec()));
                        Some(FrameAck { frame: hd.frame, round: 0, state: FrameState::Complete })
                    }
                    _ => None,
                },
                HostToBoard::FramePoll { header, round } => self.asm.poll(header, round, w, h).ok(),
                _ => None,
            };
            if let Some(a) = ack {
                replies.push(encode_message_vec(seq.next(), &BoardToHost::FrameAck(a)).unwrap());
            }
        }
        replies
    }
}

/// Runs `frames` images through the line; the host gives up on a frame after `patience`
/// rounds (superseding it), or never when `None`. Returns the images sent by id and the board.
fn run(
    size: [u16; 2],
    chunk: u16,
    frames: usize,
    line: Line,
    patience: Option<u32>,
    seed: u64,
) -> (HashMap<u16, Vec<u8>>, BoardSide, Vec<bool>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = size[0] as usize * size[1] as usize;
    let mut board = BoardSide { rx: Rx::new(), asm: Box::new(Assembly::new()), size, completed: Vec::new() };
    let (mut host_seq, mut board_seq) = (Sequencer::default(), Sequencer::default());
    let mut host_rx = Rx::new();
    let mut sent = HashMap::new();
    let mut finished = Vec::new();
    let mut now = 0u64;
    for k in 0..frames {
        let id = 1000u16.wrapping_add(k as u16 * 3);
        let px: Vec<u8> = (0..n).map(|_| rng.gen()).collect();
        let h = face_header(id, [1, 2], size, chunk, &px);
        sent.insert(id, px.clone());
        let mut s = FaceSender::new(h, 5);
        let mut rounds = 0;
        while s.finished().is_none() && patience.is_none_or(|p| rounds < p) && rounds < 2000 {
            rounds += 1;
            let mut batch = Vec::new();
            while let Some(m) = s.next(&px) {
                batch.push(encode(&m, &mut host_seq, line, &mut rng));
            }
            s.sent(now);
            let mut replies = Vec::new();
            for w in transmit(batch, line, &mut rng) {
                replies.extend(board.take(&w, &mut board_seq));
            }
            for w in transmit(replies, line, &mut rng) {
                for &b in &w {
                    if let Some(Ok(f)) = host_rx.push(b) {
                        if let Ok(BoardToHost::FrameAck(a)) = f.message::<BoardToHost>() {
                            s.on_ack(&a);
                        }
                    }
                }
            }
            now += 10;
            s.check(now);
        }
        finished.push(s.finished() == Some(FrameState::Complete));
    }
    (sent, board, finished)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Every image the board completes is byte-identical to the one the host sent under that
    /// id, and each is completed at most once; the host believes a frame complete only if the
    /// board completed it.
    #[test]
    fn the_pipeline_sees_only_what_the_host_sent(
        w in 1u16..=96, h in 1u16..=64, chunk in MIN_CHUNK as u16..=240,
        frames in 1usize..6, line in line(), patience in proptest::option::of(1u32..6), seed: u64,
    ) {
        let (sent, board, finished) = run([w, h], chunk, frames, line, patience, seed);
        let mut seen = std::collections::HashSet::new();
        for (id, px) in &board.completed {
            prop_assert_eq!(Some(px), sent.get(id), "frame {} differs", id);
            prop_assert!(seen.insert(*id), "frame {} processed twice", id);
        }
        for (k, ok) in finished.iter().enumerate() {
            let id = 1000u16.wrapping_add(k as u16 * 3);
            prop_assert!(!ok || seen.contains(&id), "host thinks {} arrived", id);
        }
    }

    /// With the host patient, every frame arrives however bad the line (under half lost).
    #[test]
    fn a_patient_host_gets_every_frame_through(line in line(), seed: u64) {
        // No forged chunks here: each would cost a whole frame again (and is a CRC-16 miss,
        // about 1 in 65536 damaged frames).
        let line = Line { forge: 0, ..line };
        let (_, board, finished) = run([58, 75], 64, 3, line, None, seed);
        prop_assert!(finished.iter().all(|f| *f), "{:?}", finished);
        prop_assert_eq!(board.completed.len(), 3);
    }
}

#[test]
fn a_superseded_frame_is_never_processed() {
    // Chunks of frame 1 arrive, then frame 2 starts: frame 1's late chunks and poll change
    // nothing, and frame 2 completes alone.
    let mut a = Box::new(Assembly::new());
    let px1 = vec![1u8; 100];
    let px2 = vec![2u8; 100];
    let h1 = face_header(1, [0, 0], [10, 10], 24, &px1);
    let h2 = face_header(2, [0, 0], [10, 10], 24, &px2);
    a.start(h1, 10, 10).unwrap();
    assert_eq!(a.chunk(1, 0, &px1[..24]), Ok(Progress::Quiet));
    a.start(h2, 10, 10).unwrap();
    assert_eq!(a.superseded, 1);
    for i in 1..5 {
        let r = h1.chunk_range(i);
        assert_eq!(a.chunk(1, r.start as u16, &px1[r]), Ok(Progress::Quiet));
    }
    assert_eq!(a.poll(h1, 1, 10, 10).unwrap().state, FrameState::Stale);
    let mut last = Progress::Quiet;
    for i in 0..5 {
        let r = h2.chunk_range(i);
        last = a.chunk(2, r.start as u16, &px2[r]).unwrap();
    }
    assert_eq!(last, Progress::Complete(h2));
    assert_eq!(a.pixels(&h2), &px2[..]);
    // Wrong sizes are refused and keep nothing from changing.
    assert_eq!(a.start(FrameHeader { frame: 3, ..h2 }, 10, 11), Err(AssemblyError::Size));
    assert_eq!(a.start(FrameHeader { frame: 3, chunk: 23, ..h2 }, 10, 10), Err(AssemblyError::Size));
    // A face position past a pixel from the crop is not a position: refused too.
    assert_eq!(a.start(FrameHeader { frame: 3, crop_sub: [65, 0], ..h2 }, 10, 10), Err(AssemblyError::Size));
    assert_eq!(a.start(FrameHeader { frame: 3, crop_sub: [0, -65], ..h2 }, 10, 10), Err(AssemblyError::Size));
    a.start(FrameHeader { frame: 4, ..h2 }, 10, 10).unwrap();
    assert_eq!(a.chunk(4, 5, &px2[..24]), Err(AssemblyError::Chunk));
    assert_eq!(a.chunk(4, 96, &px2[..24]), Err(AssemblyError::Chunk), "the last chunk is 4 bytes");
    assert_eq!(a.chunk(4, 120, &px2[..4]), Err(AssemblyError::Chunk), "past the end");
    assert_eq!(a.chunk(4, 96, &px2[..4]), Ok(Progress::Ack(FrameAck {
        frame: 4,
        round: 0,
        state: FrameState::Missing(ChunkSet::first(4)),
    })));
}
