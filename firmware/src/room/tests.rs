use super::*;

const W: usize = 64;
const H: usize = 48;

/// A frame whose fitted grey levels sit `shift` grey levels above the prediction on the left
/// half (x < 32) and on it elsewhere: a shading change that no gain and offset make (the
/// prediction gets brighter down the face, the change is left against right).
fn frame(shift: u16) -> (Vec<u8>, Vec<u16>, crate::light::Lut) {
    let lut = crate::light::Lut::IDENTITY;
    let pred: Vec<u16> = (0..W * H).map(|i| (60 + 2 * (i / W) as u16) << 8).collect();
    let frame = (0..W * H)
        .map(|i| {
            let p = (pred[i] >> 8) as u8;
            if i % W < 32 { p + shift as u8 } else { p }
        })
        .collect();
    (frame, pred, lut)
}

/// `n` frames of [`frame`] as the board learns them: against the prediction with the offsets,
/// each followed by a frame it does not learn from, which settles a complete batch.
fn learn_n(room: &mut Room, n: usize, shift: u16, mask: &[u8], t0: u64) -> u64 {
    let (f, p, lut) = frame(shift);
    let mut t = t0;
    for _ in 0..n {
        let mut q = p.clone();
        room.apply(&mut q, W);
        room.learn(t, &f, &q, &lut, mask, W);
        room.settle();
        t += MIN_GAP_US;
    }
    t
}

/// A batch's update waits for the next frame; learnt from instead, that frame only settles
/// (its prediction has the offsets of before), so no frame pays for both.
#[test]
fn the_update_comes_on_the_frame_after_the_batch() {
    let mut room = Room::new();
    let mask = vec![0u8; W * H];
    let (f, p, lut) = frame(4);
    for k in 0..BATCH as u64 {
        assert!(!room.learn(k * MIN_GAP_US, &f, &p, &lut, &mask, W));
    }
    assert!(room.pending());
    assert!(room.offsets().iter().all(|&o| o == 0), "nothing moves on the batch's last frame");
    let g = room.generation();
    // The very next frame, inside the gap between two frames learnt from.
    let last = (BATCH as u64 - 1) * MIN_GAP_US;
    assert!(room.learn(last + 1000, &f, &p, &lut, &mask, W), "the next learn settles");
    assert!(!room.pending());
    assert_ne!(room.generation(), g);
    assert_eq!(room.report(true).frames, BATCH as u32, "and is not learnt from");
    assert_eq!(room.report(true).updates, 1);
    assert!(!room.settle(), "nothing waits any more");
    // The board's way: learnt, then settled on a frame between.
    let mut board = Room::new();
    learn_n(&mut board, BATCH as usize, 4, &mask, 0);
    assert_eq!(board.offsets(), room.offsets());
    // A freeze drops a complete batch with the rest.
    let mut frozen = Room::new();
    for k in 0..BATCH as u64 {
        frozen.learn(k * MIN_GAP_US, &f, &p, &lut, &mask, W);
    }
    frozen.freeze(true);
    assert!(!frozen.pending() && !frozen.settle());
}

#[test]
fn follows_a_shading_change_slowly_and_no_further_than_the_limit() {
    let mut room = Room::new();
    let mask = vec![0u8; W * H];
    // One batch: 1/8 of 4 grey levels (1024 Q8.8) on the left, nothing on the right; less the
    // part a uniform offset makes (the fit's): +64 on the left, -64 on the right.
    learn_n(&mut room, BATCH as usize, 4, &mask, 0);
    assert!((62..=66).contains(&room.offset_at(0, 0)), "{}", room.offset_at(0, 0));
    assert!((-66..=-62).contains(&room.offset_at(40, 47)), "{}", room.offset_at(40, 47));
    assert_eq!(room.report(true).updates, 1);
    // Many batches: it settles at the shift, as +-2 grey levels (uniform part taken out).
    learn_n(&mut room, 400 * BATCH as usize, 4, &mask, 10_000_000);
    for (x, y, want) in [(10, 30, 512), (0, 0, 512), (40, 0, -512), (63, 47, -512)] {
        let o = room.offset_at(x, y) as i32;
        assert!((o - want).abs() <= 64, "({x}, {y}): {o}");
    }
    // A shift past the limit stops at the limit.
    learn_n(&mut room, 400 * BATCH as usize, 40, &mask, 10_000_000_000);
    assert_eq!(room.offset_at(0, 0), LIMIT);
    assert_eq!(room.offset_at(40, 47), -LIMIT);
    assert!(room.offsets().iter().all(|o| o.abs() <= LIMIT));
    assert!(room.report(true).at_limit >= 12);
}

#[test]
fn salient_and_clipped_pixels_teach_nothing() {
    let mut room = Room::new();
    // Every pixel of the left half salient (a mark): nothing learnt there.
    let mask: Vec<u8> = (0..W * H).map(|i| (i % W < 32) as u8).collect();
    learn_n(&mut room, 4 * BATCH as usize, 4, &mask, 0);
    assert!(room.offsets().iter().all(|&o| o == 0));
    // Clipped pixels: a frame at 255 where the prediction is 100 teaches nothing either.
    let (_, p, lut) = frame(0);
    let f = vec![255u8; W * H];
    let mask = vec![0u8; W * H];
    for k in 0..4 * BATCH as u64 {
        room.learn(k * MIN_GAP_US, &f, &p, &lut, &mask, W);
    }
    assert!(room.offsets().iter().all(|&o| o == 0));
}

#[test]
fn learns_at_a_bounded_rate_and_not_when_frozen() {
    let mut room = Room::new();
    let mask = vec![0u8; W * H];
    let (f, p, lut) = frame(4);
    // Frames closer than MIN_GAP_US: only the first counts.
    for k in 0..100u64 {
        room.learn(k * 1000, &f, &p, &lut, &mask, W);
    }
    assert_eq!(room.report(true).frames, 1);
    room.freeze(true);
    learn_n(&mut room, 10 * BATCH as usize, 4, &mask, 1_000_000);
    assert_eq!(room.report(true).frames, 1);
    assert_eq!(room.report(true).state, RoomState::Frozen);
    assert_eq!(room.report(false).state, RoomState::Off);
    room.freeze(false);
    learn_n(&mut room, BATCH as usize, 4, &mask, 100_000_000);
    assert!(room.offset_at(0, 0) > 0);
    let g = room.generation();
    room.reset();
    assert!(room.offsets().iter().all(|&o| o == 0));
    assert_ne!(room.generation(), g, "a reset remakes the threshold table");
}

#[test]
fn the_prediction_takes_the_offsets() {
    let mut room = Room::new();
    let mask = vec![0u8; W * H];
    learn_n(&mut room, 400 * BATCH as usize, 4, &mask, 0);
    let mut pred = vec![10_000u16; W * H];
    pred[1] = 65270;
    pred[41] = 100;
    room.apply(&mut pred, W);
    let (left, right) = (room.offset_at(2, 0) as i32, room.offset_at(40, 0) as i32);
    assert!(left > 400 && right < -400, "{left} {right}");
    assert_eq!(pred[1], 65280, "stays a grey level");
    assert_eq!(pred[41], 0, "stays a grey level");
    assert_eq!(pred[2] as i32, 10_000 + left);
    assert_eq!(pred[40] as i32, 10_000 + right);
    assert_eq!(pred[2 * W + 40] as i32, 10_000 + right);
}

#[test]
fn saved_offsets_come_back_and_anything_else_is_refused() {
    let mut room = Room::new();
    let mask = vec![0u8; W * H];
    learn_n(&mut room, 40 * BATCH as usize, 4, &mask, 0);
    let mut bytes = [0u8; SAVED_LEN];
    room.save(&mut bytes);
    let mut back = Room::new();
    assert!(back.restore(&bytes));
    assert_eq!(back.offsets(), room.offsets());
    // Truncated, another version, an offset past the limit: refused, nothing changed.
    let mut other = Room::new();
    assert!(!other.restore(&bytes[..SAVED_LEN - 1]));
    let mut v2 = bytes;
    v2[0] = 2;
    assert!(!other.restore(&v2));
    let mut far = bytes;
    far[4..6].copy_from_slice(&(LIMIT + 1).to_le_bytes());
    assert!(!other.restore(&far));
    assert!(other.offsets().iter().all(|&o| o == 0));
}

/// Every offset a cell may hold, at its sign's ends and around 0, on predictions over the whole
/// u16 range (past the grey range too), a face of odd width whose odd rows start between words:
/// `apply` is `(min(p, 65280) + o).clamp(0, 255 << 8)`.
#[test]
fn apply_is_the_clamped_sum() {
    let mut room = Room::new();
    let offsets = [-LIMIT, -1000, -1, 0, 1, 1000, LIMIT];
    room.set_offsets(&core::array::from_fn(|c| offsets[c % offsets.len()]));
    for w in [MAX_FACE_W, 75, 9, 8, 7, 1] {
        let mut pred: Vec<u16> = (0..w * MAX_FACE_H).map(|i| (i as u32 * 7919 % 65536) as u16).collect();
        let n = pred.len();
        pred[3 % n] = 65535;
        pred[4 % n] = 65280;
        pred[5 % n] = 0;
        let before = pred.clone();
        room.apply(&mut pred, w);
        for (i, (&p, &q)) in before.iter().zip(&pred).enumerate() {
            let o = room.offset_at(i % w, i / w) as i32;
            assert_eq!(q as i32, (p.min(255 << 8) as i32 + o).clamp(0, 255 << 8), "width {w}, pixel {i}, offset {o}");
        }
    }
}

/// The two saturating steps of a packed offset are the definition for every value and every
/// offset a cell can hold (and the i16 extremes the board's check feeds the routine).
#[test]
fn packed_offsets_are_the_definition() {
    let offsets = (-LIMIT..=LIMIT).step_by(97).chain([-LIMIT, -256, -255, -1, 0, 1, 255, 256, LIMIT, i16::MIN, i16::MAX]);
    for o in offsets {
        let k = rows::Packed::of(o);
        assert_eq!(k.add >> 16, k.add & 0xffff);
        assert_eq!(k.sub >> 16, k.sub & 0xffff);
        for p in 0..=u16::MAX {
            let want = (p.min(255 << 8) as i32 + o as i32).clamp(0, 255 << 8);
            assert_eq!(k.add_to(p) as i32, want, "p {p}, o {o}");
        }
    }
}

/// A new offset reaches rule 4 (the packed words follow every update, restore and reset).
#[test]
fn apply_follows_the_offsets() {
    let mut room = Room::new();
    let mut pred = vec![1000u16; 75 * 58];
    room.apply(&mut pred, 75);
    assert!(pred.iter().all(|&p| p == 1000), "offsets 0 add nothing");
    let mut saved = [0u8; SAVED_LEN];
    let mut other = Room::new();
    let mut first = [0; CELLS];
    first[0] = 300;
    other.set_offsets(&first);
    other.save(&mut saved);
    assert!(room.restore(&saved));
    room.apply(&mut pred, 75);
    assert_eq!(pred[0], 1300);
    assert_eq!(pred[8], 1000, "the next cell's offset is 0");
    room.reset();
    room.apply(&mut pred, 75);
    assert_eq!(pred[0], 1300, "after a reset nothing is added");
}

/// Rule 2's samples are the pixels at even x and even y (the cells are 8 wide), on a face of odd
/// width whose last cells are 3 pixels wide: one frame's sums per cell against that plain rule,
/// pixels at or past the clip levels left out.
#[test]
fn a_frame_teaches_every_second_pixel_of_every_second_row() {
    let (w, h) = (75usize, 58usize);
    let mut rng = 0x1234_5677u32;
    let mut next = move || {
        rng ^= rng << 13;
        rng ^= rng >> 17;
        rng ^= rng << 5;
        rng
    };
    let f: Vec<u8> = (0..w * h).map(|_| next() as u8).collect();
    let p: Vec<u16> = (0..w * h).map(|_| next() as u16).collect();
    let m: Vec<u8> = (0..w * h).map(|_| (next() % 5 == 0) as u8).collect();
    // The camera's own clip levels, a plateau's, and none left between them.
    for (lo, hi) in [(0u8, 255u8), (20, 200), (99, 100)] {
        let lut = crate::light::Lut { lo, hi, ..crate::light::Lut::IDENTITY };
        let mut room = Room::new();
        room.learn(0, &f, &p, &lut, &m, w);
        let mut want = [(0i32, 0i32, 0u32); CELLS];
        for y in (0..h).step_by(2) {
            for x in (0..w).step_by(2) {
                let i = y * w + x;
                if m[i] == 0 && f[i] > lo && f[i] < hi {
                    let c = &mut want[(y / CELL) * COLS + x / CELL];
                    c.0 += lut.v[f[i] as usize] as i32 - p[i] as i32;
                    c.1 += p[i] as i32;
                    c.2 += 1;
                }
            }
        }
        let got: Vec<(i32, i32, u32)> = room.acc.iter().map(|a| (a.sum, a.pred, a.count)).collect();
        assert_eq!(got, want.to_vec(), "clip levels {lo} {hi}");
        if hi - lo > 100 {
            assert!(want.iter().filter(|c| c.2 > 0).count() > 50, "the frame taught most cells");
        }
    }
}

/// What the decoder's last layer adds ([`Room::halves`], an entry a half cell) is what
/// [`Room::apply`] adds, and there is nothing to add while every offset is 0.
#[test]
fn the_halves_add_what_apply_adds() {
    let mut room = Room::new();
    assert!(room.halves().is_none());
    room.set_offsets(&core::array::from_fn(|c| ((c as i32 * 977) % (2 * LIMIT as i32 + 1) - LIMIT as i32) as i16));
    let halves = room.halves().expect("offsets not all 0");
    for w in [MAX_FACE_W, 75, 9, 1] {
        let pred: Vec<u16> = (0..w * MAX_FACE_H).map(|i| (i as u32 * 7919 % 65281) as u16).collect();
        let mut applied = pred.clone();
        room.apply(&mut applied, w);
        for (i, (&p, &q)) in pred.iter().zip(&applied).enumerate() {
            let (x, y) = (i % w, i / w);
            assert_eq!(halves[(y / CELL) * 2 * COLS + x / HALF].add_to(p), q, "width {w}, pixel {i}");
        }
    }
}
