//! The e-Manual's own examples (Protocol 2.0 page, "Instruction Details"), byte for byte.
use super::*;
use proptest::prelude::*;

// Ping, example 1: ID 1; its status: XM430-W210, model 1030 (0x0406), firmware 38.
const PING_1: [u8; 10] = [0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x03, 0x00, 0x01, 0x19, 0x4E];
const PING_1_STATUS: [u8; 14] =
    [0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x07, 0x00, 0x55, 0x00, 0x06, 0x04, 0x26, 0x65, 0x5D];
// Ping, example 2: broadcast; ID 2's status.
const PING_ALL: [u8; 10] = [0xFF, 0xFF, 0xFD, 0x00, 0xFE, 0x03, 0x00, 0x01, 0x31, 0x42];
const PING_2_STATUS: [u8; 14] =
    [0xFF, 0xFF, 0xFD, 0x00, 0x02, 0x07, 0x00, 0x55, 0x00, 0x06, 0x04, 0x26, 0x6F, 0x6D];
// Read Present Position (132, 4 bytes) of ID 1 = 166.
const READ_1: [u8; 14] =
    [0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x07, 0x00, 0x02, 0x84, 0x00, 0x04, 0x00, 0x1D, 0x15];
const READ_1_STATUS: [u8; 15] =
    [0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x08, 0x00, 0x55, 0x00, 0xA6, 0x00, 0x00, 0x00, 0x8C, 0xC0];
// Write 512 to Goal Position (116) of ID 1, and the empty status.
const WRITE_1: [u8; 16] = [
    0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x09, 0x00, 0x03, 0x74, 0x00, 0x00, 0x02, 0x00, 0x00, 0xCA, 0x89,
];
const EMPTY_STATUS_1: [u8; 11] = [0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x04, 0x00, 0x55, 0x00, 0xA1, 0x0C];
// Sync Read Present Position of IDs 1 and 2; ID 2 answers 2079 (0x081F).
const SYNC_READ_12: [u8; 16] = [
    0xFF, 0xFF, 0xFD, 0x00, 0xFE, 0x09, 0x00, 0x82, 0x84, 0x00, 0x04, 0x00, 0x01, 0x02, 0xCE, 0xFA,
];
const SYNC_READ_2_STATUS: [u8; 15] =
    [0xFF, 0xFF, 0xFD, 0x00, 0x02, 0x08, 0x00, 0x55, 0x00, 0x1F, 0x08, 0x00, 0x00, 0xBA, 0xBE];
// Sync Write Goal Position: ID 1 <- 150, ID 2 <- 170.
const SYNC_WRITE_12: [u8; 24] = [
    0xFF, 0xFF, 0xFD, 0x00, 0xFE, 0x11, 0x00, 0x83, 0x74, 0x00, 0x04, 0x00, 0x01, 0x96, 0x00,
    0x00, 0x00, 0x02, 0xAA, 0x00, 0x00, 0x00, 0x82, 0x87,
];
// Other e-Manual examples that only exercise the CRC: Reg Write, Action, Bulk Read.
const REG_WRITE_1: [u8; 16] = [
    0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x09, 0x00, 0x04, 0x68, 0x00, 0xC8, 0x00, 0x00, 0x00, 0xAE, 0x8E,
];
const ACTION_1: [u8; 10] = [0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x03, 0x00, 0x05, 0x02, 0xCE];
const BULK_READ_2_STATUS: [u8; 12] =
    [0xFF, 0xFF, 0xFD, 0x00, 0x02, 0x05, 0x00, 0x55, 0x00, 0x24, 0x8B, 0xA9];

fn enc(f: impl FnOnce(&mut [u8]) -> Result<usize, EncodeError>) -> Vec<u8> {
    let mut buf = [0u8; 256];
    let n = f(&mut buf).unwrap();
    buf[..n].to_vec()
}

/// Parses exactly one packet from `bytes` and returns (id, instruction, params).
fn one(bytes: &[u8]) -> (u8, u8, Vec<u8>) {
    let mut rx = Receiver::<256>::new();
    let mut got = Vec::new();
    for &b in bytes {
        rx.push(b);
        while let Some(p) = rx.next_packet() {
            got.push((p.id, p.instruction, p.params.to_vec()));
        }
    }
    assert_eq!(got.len(), 1, "{bytes:02X?} gave {got:?}");
    assert_eq!(rx.counters().errors(), 0);
    got.pop().unwrap()
}

#[test]
fn crc_of_the_manual_examples() {
    for p in [
        &PING_1[..], &PING_1_STATUS, &PING_ALL, &PING_2_STATUS, &READ_1, &READ_1_STATUS,
        &WRITE_1, &EMPTY_STATUS_1, &SYNC_READ_12, &SYNC_READ_2_STATUS, &SYNC_WRITE_12,
        &REG_WRITE_1, &ACTION_1, &BULK_READ_2_STATUS,
    ] {
        let n = p.len();
        assert_eq!(CRC16.checksum(&p[..n - 2]).to_le_bytes(), [p[n - 2], p[n - 1]], "{p:02X?}");
    }
}

#[test]
fn encodes_the_manual_instructions() {
    assert_eq!(enc(|b| ping(1, b)), PING_1);
    assert_eq!(enc(|b| ping(BROADCAST, b)), PING_ALL);
    assert_eq!(enc(|b| read(1, 132, 4, b)), READ_1);
    assert_eq!(enc(|b| write(1, 116, &512u32.to_le_bytes(), b)), WRITE_1);
    assert_eq!(enc(|b| sync_read(132, 4, &[1, 2], b)), SYNC_READ_12);
    let (a, c) = (150u32.to_le_bytes(), 170u32.to_le_bytes());
    assert_eq!(enc(|b| sync_write(116, 4, [(1, &a[..]), (2, &c[..])], b)), SYNC_WRITE_12);
}

#[test]
fn encodes_the_manual_statuses() {
    assert_eq!(enc(|b| status(1, 0, &[0x06, 0x04, 0x26], b)), PING_1_STATUS);
    assert_eq!(enc(|b| status(2, 0, &[0x06, 0x04, 0x26], b)), PING_2_STATUS);
    assert_eq!(enc(|b| status(1, 0, &166u32.to_le_bytes(), b)), READ_1_STATUS);
    assert_eq!(enc(|b| status(2, 0, &2079u32.to_le_bytes(), b)), SYNC_READ_2_STATUS);
    assert_eq!(enc(|b| status(1, 0, &[], b)), EMPTY_STATUS_1);
}

#[test]
fn parses_the_manual_statuses() {
    let (id, i, p) = one(&PING_1_STATUS);
    let s = Status::of(&Packet { id, instruction: i, params: &p }).unwrap();
    assert_eq!((s.id, s.error, s.value(2), s.params[2]), (1, 0, None, 0x26));
    assert_eq!(u16::from_le_bytes([s.params[0], s.params[1]]), 1030);
    for (bytes, id, pos) in [(&READ_1_STATUS, 1, 166), (&SYNC_READ_2_STATUS, 2, 2079)] {
        let (pid, i, p) = one(bytes);
        let s = Status::of(&Packet { id: pid, instruction: i, params: &p }).unwrap();
        assert_eq!((s.id, s.alert(), s.error_number(), s.value(4)), (id, false, 0, Some(pos)));
    }
    let (id, i, p) = one(&EMPTY_STATUS_1);
    let s = Status::of(&Packet { id, instruction: i, params: &p }).unwrap();
    assert_eq!((s.id, s.error, s.params), (1, 0, &[][..]));
}

#[test]
fn parses_the_manual_instructions() {
    let view = |bytes: &[u8]| {
        let (id, i, p) = one(bytes);
        (id, format!("{:?}", Instruction::of(&Packet { id, instruction: i, params: &p })))
    };
    assert_eq!(view(&PING_ALL), (0xFE, "Ping".into()));
    assert_eq!(view(&READ_1), (1, "Read { addr: 132, len: 4 }".into()));
    assert_eq!(view(&WRITE_1), (1, "Write { addr: 116, data: [0, 2, 0, 0] }".into()));
    assert_eq!(view(&SYNC_READ_12), (0xFE, "SyncRead { addr: 132, len: 4, ids: [1, 2] }".into()));
    let (id, i, p) = one(&SYNC_WRITE_12);
    let sw = Instruction::of(&Packet { id, instruction: i, params: &p });
    let entries: Vec<(u8, Vec<u8>)> = sw.sync_entries().map(|(id, d)| (id, d.to_vec())).collect();
    assert_eq!(entries, vec![(1, vec![0x96, 0, 0, 0]), (2, vec![0xAA, 0, 0, 0])]);
    assert_eq!(view(&PING_1_STATUS).1, "Status");
}

// The e-Manual gives the stuffing rule but no stuffed example packet; this one is worked by hand
// from the rule (FF FF FD in instruction..parameters gets an extra FD, LEN and CRC count it).
// Write [FF FF FD 00] to Goal Position of ID 1: body 03 74 00 FF FF FD 00 -> 03 74 00 FF FF FD FD 00,
// LEN = 8 + 2 = 10.
#[test]
fn stuffing_both_ways() {
    let data = [0xFF, 0xFF, 0xFD, 0x00];
    let wire = enc(|b| write(1, 116, &data, b));
    assert_eq!(
        &wire[..15],
        &[0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x0A, 0x00, 0x03, 0x74, 0x00, 0xFF, 0xFF, 0xFD, 0xFD, 0x00]
    );
    assert_eq!(wire.len(), 17);
    assert_eq!(CRC16.checksum(&wire[..15]).to_le_bytes(), [wire[15], wire[16]]);
    let (id, i, p) = one(&wire);
    assert_eq!((id, i, &p[..]), (1, inst::WRITE, &[0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x00][..]));
    // A status whose error byte and first parameter make FF FF FD across the boundary.
    let wire = enc(|b| status(3, 0xFF, &[0xFF, 0xFD, 0xFD], b));
    assert_eq!(&wire[7..13], &[0x55, 0xFF, 0xFF, 0xFD, 0xFD, 0xFD]);
    let (_, _, p) = one(&wire);
    assert_eq!(p, vec![0xFF, 0xFF, 0xFD, 0xFD]);
    // Unstuffed FF FF FD inside a packet (with a good CRC) is refused.
    let mut bad = vec![0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x07, 0x00, 0x55, 0x00, 0xFF, 0xFF, 0xFD];
    let crc = CRC16.checksum(&bad);
    bad.extend_from_slice(&crc.to_le_bytes());
    let mut rx = Receiver::<64>::new();
    for &b in &bad {
        rx.push(b);
        assert!(rx.next_packet().is_none());
    }
    assert_eq!(rx.counters().bad_stuffing, 1);
}

#[test]
fn resynchronises_after_noise_and_damage() {
    let mut stream = vec![0x00, 0xFF, 0x13, 0xFF, 0xFF];
    stream.extend_from_slice(&READ_1_STATUS);
    let mut broken = SYNC_READ_2_STATUS;
    broken[10] ^= 0x01;
    stream.extend_from_slice(&broken);
    stream.extend_from_slice(&SYNC_READ_2_STATUS);
    let mut rx = Receiver::<64>::new();
    let mut got = Vec::new();
    for &b in &stream {
        rx.push(b);
        while let Some(p) = rx.next_packet() {
            got.push(Status::of(&p).and_then(|s| s.value(4)));
        }
    }
    assert_eq!(got, vec![Some(166), Some(2079)]);
    assert_eq!(rx.counters().crc_errors, 1);
    assert_eq!(rx.counters().packets, 2);
}

#[test]
fn refuses_bad_ids_lengths_and_oversize() {
    let mut rx = Receiver::<16>::new();
    for bytes in [
        &[0xFF, 0xFF, 0xFD, 0x00, 0xFF, 0x03, 0x00][..],
        &[0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x02, 0x00],
        &[0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x20, 0x00],
    ] {
        for &b in bytes {
            rx.push(b);
            assert!(rx.next_packet().is_none());
        }
    }
    let c = rx.counters();
    assert_eq!((c.bad_id, c.bad_length, c.oversized), (1, 1, 1));
    // A status without its error byte.
    let mut p = vec![0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x03, 0x00, 0x55];
    let crc = CRC16.checksum(&p);
    p.extend_from_slice(&crc.to_le_bytes());
    let mut rx = Receiver::<16>::new();
    for &b in &p {
        rx.push(b);
        assert!(rx.next_packet().is_none());
    }
    assert_eq!(rx.counters().bad_length, 1);
    // Encoding refuses IDs that are not IDs and buffers that are too small.
    assert_eq!(ping(0xFD, &mut [0; 16]), Err(EncodeError::Invalid));
    assert_eq!(sync_read(132, 4, &[1, 0xFE], &mut [0; 32]), Err(EncodeError::Invalid));
    assert_eq!(write(1, 116, &[0; 8], &mut [0; 16]), Err(EncodeError::TooLong));
    assert_eq!(sync_write(116, 4, [(1, &[0u8; 2][..])], &mut [0; 32]), Err(EncodeError::Invalid));
}

fn statuses(bytes: &[u8]) -> Vec<(u8, Option<u32>)> {
    let mut rx = Receiver::<64>::new();
    let mut out = Vec::new();
    for &b in bytes {
        rx.push(b);
        while let Some(p) = rx.next_packet() {
            if let Some(s) = Status::of(&p) {
                out.push((s.id, s.value(4)));
            }
        }
    }
    out
}

proptest! {
    #[test]
    fn random_bytes_never_panic_nor_give_a_position(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        let mut copy = bytes.clone();
        let _ = parse(&mut copy, 64);
        prop_assert!(statuses(&bytes).is_empty());
    }

    #[test]
    fn random_bytes_after_a_header_never_give_a_position(
        id in 0u8..=0xFC, len in 3u16..40, rest in proptest::collection::vec(any::<u8>(), 0..60)
    ) {
        let mut bytes = vec![0xFF, 0xFF, 0xFD, 0x00, id];
        bytes.extend_from_slice(&len.to_le_bytes());
        bytes.push(inst::STATUS);
        bytes.extend_from_slice(&rest);
        // A CRC that happens to match is a real packet (1 in 65536): only a wrong one is tested.
        let n = PREFIX_LEN + len as usize;
        prop_assume!(bytes.len() < n || CRC16.checksum(&bytes[..n - 2]).to_le_bytes() != [bytes[n - 2], bytes[n - 1]]);
        prop_assert!(statuses(&bytes).is_empty());
    }

    #[test]
    fn any_packet_round_trips(id in 0u8..=0xFC, error: u8, params in proptest::collection::vec(
        prop_oneof![Just(0xFFu8), Just(0xFDu8), any::<u8>()], 0..40)
    ) {
        let wire = enc(|b| status(id, error, &params, b));
        let (pid, i, p) = one(&wire);
        prop_assert_eq!((pid, i), (id, inst::STATUS));
        prop_assert_eq!(p[0], error);
        prop_assert_eq!(&p[1..], &params[..]);
    }

    /// CRC-16 with 0x8005 catches every burst of up to 16 flipped bits inside the bytes it
    /// covers (outside the length field, which changes where the CRC sits and which the board
    /// checks against the length it asked for). Not a burst that runs from the last parameter
    /// into the CRC: Protocol 2.0 sends the CRC low byte first, so such a burst is not one burst
    /// of the polynomial, and some pass (see `a_burst_into_the_crc_can_pass`).
    #[test]
    fn damaged_positions_are_never_used(pos: u32, bit in 0usize..120, burst in 1u32..=0xFFFF) {
        let mut wire = enc(|b| status(7, 0, &pos.to_le_bytes(), b));
        let covered = (wire.len() - 2) * 8;
        let bit = bit % (covered - 32);
        let bit = if bit >= 40 { bit + 16 } else { bit }; // skip bytes 5 and 6 (LEN)
        for k in 0..16 {
            if burst & (1 << k) != 0 {
                let b = bit + k;
                if !(40..56).contains(&b) {
                    wire[b / 8] ^= 1 << (b % 8);
                }
            }
        }
        let got = statuses(&wire);
        prop_assert!(got.iter().all(|&(id, v)| id == 7 && v == Some(pos)), "{:?}", got);
    }
}

/// What the CRC-16 cannot promise (found by the proptest above when its bursts could reach the
/// CRC): position 0 with the last parameter byte XOR 0x3F and the CRC's low byte XOR 0x82 is a
/// valid packet again. The last parameter is a Present Position's top byte, 0 for every count of
/// one turn, so such a burst makes it nonzero, and the board's bus master takes only positions
/// within one turn (`0..=4095`; `firmware/src/dynamixel.rs`): this one is counted as a bad
/// answer, not used.
#[test]
fn a_burst_into_the_crc_can_pass() {
    let mut wire = enc(|b| status(7, 0, &0u32.to_le_bytes(), b));
    let n = wire.len();
    wire[n - 3] ^= 0x3F;
    wire[n - 2] ^= 0x82;
    assert_eq!(statuses(&wire), vec![(7, Some(0x3F00_0000))]);
}

/// Every odd number of flipped bits is caught wherever it falls (0x8005 is a multiple of
/// x + 1), CRC bytes included.
#[test]
fn single_bit_errors_anywhere_are_caught() {
    let clean = enc(|b| status(7, 0, &0x1234_5678u32.to_le_bytes(), b));
    for b in (0..clean.len() * 8).filter(|b| !(40..56).contains(b)) {
        let mut wire = clean.clone();
        wire[b / 8] ^= 1 << (b % 8);
        assert!(statuses(&wire).iter().all(|&(id, v)| id == 7 && v == Some(0x1234_5678)), "bit {b}");
    }
}
