use super::*;
use msr_shared::blob::U16Table;

const W: usize = 64;
const H: usize = 48;

/// A frame whose fitted grey levels sit `shift` grey levels above the prediction on the left
/// half (x < 32) and on the prediction elsewhere; mu 0, nothing salient.
fn frame(shift: u16) -> (Vec<u8>, Vec<u16>, [u16; 256]) {
    let mut lut = [0u16; 256];
    for (i, v) in lut.iter_mut().enumerate() {
        *v = (i as u16) << 8;
    }
    let pred: Vec<u16> = (0..W * H).map(|i| (100 + (i % 7) as u16) << 8).collect();
    let frame = (0..W * H)
        .map(|i| {
            let p = (pred[i] >> 8) as u8;
            if i % W < 32 { p + shift as u8 } else { p }
        })
        .collect();
    (frame, pred, lut)
}

fn zeros() -> Vec<u8> {
    vec![0u8; 2 * W * H]
}

fn learn_n(room: &mut Room, n: usize, shift: u16, mask: &[u8], t0: u64) -> u64 {
    let (f, p, lut) = frame(shift);
    let mu = zeros();
    let mut t = t0;
    for _ in 0..n {
        room.learn(t, &f, &p, &lut, U16Table(&mu), mask, W);
        t += MIN_GAP_US;
    }
    t
}

#[test]
fn follows_a_shading_change_slowly_and_no_further_than_the_limit() {
    let mut room = Room::new();
    let mask = vec![0u8; W * H];
    // One batch: 1/8 of the way to 4 grey levels (1024 Q8.8) on the left, nothing on the right.
    learn_n(&mut room, BATCH as usize, 4, &mask, 0);
    assert_eq!(room.offset_at(0, 0), 1024 >> RATE_SHIFT);
    assert_eq!(room.offset_at(40, 0), 0);
    assert_eq!(room.report(true).updates, 1);
    // Many batches: it settles at the shift.
    learn_n(&mut room, 400 * BATCH as usize, 4, &mask, 10_000_000);
    assert!((1000..=1024).contains(&room.offset_at(10, 30)), "{}", room.offset_at(10, 30));
    // A shift past the limit stops at the limit.
    learn_n(&mut room, 400 * BATCH as usize, 40, &mask, 10_000_000_000);
    assert_eq!(room.offset_at(0, 0), LIMIT);
    assert!(room.report(true).at_limit > 0);
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
    let mu = zeros();
    let mask = vec![0u8; W * H];
    for k in 0..4 * BATCH as u64 {
        room.learn(k * MIN_GAP_US, &f, &p, &lut, U16Table(&mu), &mask, W);
    }
    assert!(room.offsets().iter().all(|&o| o == 0));
}

#[test]
fn learns_at_a_bounded_rate_and_not_when_frozen() {
    let mut room = Room::new();
    let mask = vec![0u8; W * H];
    let (f, p, lut) = frame(4);
    let mu = zeros();
    // Frames closer than MIN_GAP_US: only the first counts.
    for k in 0..100u64 {
        room.learn(k * 1000, &f, &p, &lut, U16Table(&mu), &mask, W);
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
fn the_table_takes_the_offsets() {
    let mut room = Room::new();
    let mask = vec![0u8; W * H];
    learn_n(&mut room, 400 * BATCH as usize, 4, &mask, 0);
    let mut table = vec![100u16; W * H];
    table[1] = 65530;
    room.apply(&mut table, W);
    assert_eq!(table[1], 65535, "saturates");
    assert_eq!(table[2], 100 + room.offset_at(2, 0) as u16);
    assert_eq!(table[40], 100);
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
