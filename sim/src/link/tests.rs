use super::*;
use embedded_io::{Read as _, ReadReady as _, Write as _};
use msr_shared::frame::{encode_payload, FrameAccumulator, MAX_WIRE_FRAME};

fn clean() -> (LinkEnd, LinkEnd) {
    link(&LinkConfig::default()).unwrap()
}

#[test]
fn bytes_are_paced_at_the_baud_rate() {
    let (mut a, mut b) = clean();
    a.write_all(&[7u8; 100]).unwrap();
    // 921600 baud, 10 bits a byte: 10.85 us a byte, 1085.07 us for 100.
    b.set_time(10);
    assert!(!b.read_ready().unwrap());
    assert_eq!(b.read(&mut [0u8; 8]).unwrap(), 0);
    b.set_time(11);
    assert_eq!(b.receive().len(), 1);
    b.set_time(1085);
    assert_eq!(b.receive().len(), 98);
    b.set_time(1086);
    assert_eq!(b.receive(), vec![7u8]);
    assert_eq!(a.tx_idle_at_us(), 1086);
    // A later write starts when the line is free, not earlier.
    a.set_time(5000);
    a.write_all(&[1, 2]).unwrap();
    b.set_time(5021);
    assert_eq!(b.receive(), vec![1]);
    b.set_time(5022);
    assert_eq!(b.receive(), vec![2]);
    // The other direction is independent and also paced.
    b.write_all(b"pong").unwrap();
    a.set_time(5022 + 43);
    assert_eq!(a.receive(), b"pon");
    a.set_time(5022 + 44);
    assert_eq!(a.receive(), b"g");
    // 9600 baud: 1.0417 ms a byte.
    let (mut a, mut b) = link(&LinkConfig { baud: 9600, ..Default::default() }).unwrap();
    a.write_all(b"ab").unwrap();
    b.set_time(1041);
    assert!(b.receive().is_empty());
    b.set_time(1042);
    assert_eq!(b.receive(), b"a");
}

fn send_through(cfg: FaultConfig, seed: u64, n: usize) -> (Vec<u8>, Vec<u8>, LaneStats) {
    let (mut a, mut b) = link(&LinkConfig { a_to_b: cfg, seed, ..Default::default() }).unwrap();
    let data: Vec<u8> = (0..n).map(|i| (i * 7 + i / 256) as u8).collect();
    a.write_all(&data).unwrap();
    b.set_time(a.tx_idle_at_us() + 1);
    (data, b.receive(), a.tx_stats())
}

#[test]
fn bit_errors_at_the_set_rate_and_seeded() {
    let (sent, got, st) = send_through(FaultConfig::ber(1e-3), 1, 100_000);
    assert_eq!(got.len(), sent.len());
    let flipped: u32 = sent.iter().zip(&got).map(|(a, b)| (a ^ b).count_ones()).sum();
    assert_eq!(flipped as u64, st.faults.bits_flipped);
    // 800000 bits at 1e-3: 800 expected, sd 28.
    assert!((700..900).contains(&flipped), "{flipped}");
    let (_, again, _) = send_through(FaultConfig::ber(1e-3), 1, 100_000);
    assert_eq!(got, again);
    let (_, other, _) = send_through(FaultConfig::ber(1e-3), 2, 100_000);
    assert_ne!(got, other);
}

#[test]
fn drops_and_bursts() {
    let (sent, got, st) = send_through(FaultConfig { drop_rate: 0.01, ..Default::default() }, 3, 100_000);
    assert_eq!(got.len() as u64, sent.len() as u64 - st.faults.bytes_dropped);
    assert!((800..1200).contains(&st.faults.bytes_dropped), "{st:?}");
    let cfg = FaultConfig { burst_rate: 1e-3, burst_len: 16, ..Default::default() };
    let (sent, got, st) = send_through(cfg, 4, 100_000);
    assert_eq!(got.len(), sent.len());
    assert!((70..130).contains(&st.faults.bursts), "{st:?}");
    let differ = sent.iter().zip(&got).filter(|(a, b)| a != b).count() as u64;
    // A random byte equals the original one time in 256.
    assert!(differ <= st.faults.burst_bytes && differ * 100 > st.faults.burst_bytes * 97, "{differ} {st:?}");
}

fn frame(seq: u16, payload: &[u8]) -> Vec<u8> {
    let mut out = [0u8; MAX_WIRE_FRAME];
    let n = encode_payload(seq, payload, &mut out).unwrap();
    out[..n].to_vec()
}

#[test]
fn a_disconnect_loses_what_was_on_the_line_then_frames_resume() {
    let cfg = FaultConfig::disconnect(100_000, 200_000);
    let (mut a, mut b) = link(&LinkConfig { a_to_b: cfg, ..Default::default() }).unwrap();
    let mut acc = FrameAccumulator::<MAX_WIRE_FRAME>::new();
    let mut got = Vec::new();
    for k in 0..50u16 {
        let t = k as u64 * 10_000;
        a.set_time(t);
        a.write_all(&frame(k, &[k as u8; 40])).unwrap();
        b.set_time(t + 9_000);
        for byte in b.receive() {
            if let Some(Ok(f)) = acc.push(byte) {
                got.push(f.seq);
            }
        }
    }
    // Frames sent from 100 ms to 299 ms are gone (20 of them); everything else arrives.
    let expect: Vec<u16> = (0..10).chain(30..50).collect();
    assert_eq!(got, expect);
    assert_eq!(acc.counters().seq_gaps, 20);
    assert!(a.tx_stats().faults.disconnect_bytes > 20 * 40);
}

#[test]
fn crc_catches_every_corrupted_frame() {
    // 2000 frames through BER 1e-3 and bursts: every frame accepted is one that was sent.
    let cfg = FaultConfig { bit_error_rate: 1e-3, burst_rate: 1e-4, burst_len: 5, ..Default::default() };
    let (mut a, mut b) = link(&LinkConfig { a_to_b: cfg, seed: 9, ..Default::default() }).unwrap();
    let payload = |k: u16| -> Vec<u8> { (0..30).map(|i| (k as usize * 31 + i) as u8).collect() };
    for k in 0..2000u16 {
        a.write_all(&frame(k, &payload(k))).unwrap();
    }
    b.set_time(a.tx_idle_at_us());
    let mut acc = FrameAccumulator::<MAX_WIRE_FRAME>::new();
    let mut good = 0;
    for byte in b.receive() {
        if let Some(Ok(f)) = acc.push(byte) {
            assert_eq!(f.payload, payload(f.seq).as_slice());
            good += 1;
        }
    }
    // About 40 bytes a frame: 1 - (1 - 1e-3)^320 = 27 % of frames hit.
    assert!((1300..1600).contains(&good), "{good}");
    assert!(acc.counters().resyncs() > 300, "{:?}", acc.counters());
}

#[test]
fn faulty_stream_wraps_std_and_embedded_streams() {
    // std::io: a Vec as the sink.
    let tx = Faults::new(FaultConfig::ber(0.05), 1);
    let rx = Faults::new(FaultConfig::default(), 2);
    let mut s = FaultyStream::new(Vec::new(), tx, rx, Box::new(|| 0));
    std::io::Write::write_all(&mut s, &[0u8; 1000]).unwrap();
    let flips: u32 = s.inner().iter().map(|b| b.count_ones()).sum();
    assert_eq!(flips as u64, s.tx_counters().bits_flipped);
    assert!(flips > 300 && flips < 500, "{flips}");
    // std::io read side with a disconnect from t = 0.
    let rx = Faults::new(FaultConfig::disconnect(0, 10), 3);
    let mut r = FaultyStream::new(std::io::Cursor::new(vec![1u8; 10]), Faults::new(FaultConfig::default(), 0), rx, Box::new(|| 5));
    let mut buf = [0u8; 16];
    assert_eq!(std::io::Read::read(&mut r, &mut buf).unwrap(), 0);
    assert_eq!(r.rx_counters().disconnect_bytes, 10);
    // embedded_io: around a link end, dropping everything written.
    let (a, mut b) = clean();
    let drop_all = Faults::new(FaultConfig { drop_rate: 1.0, ..Default::default() }, 4);
    let mut fa = FaultyIo(FaultyStream::new(a, drop_all, Faults::new(FaultConfig::default(), 5), Box::new(|| 0)));
    fa.write_all(b"lost").unwrap();
    b.set_time(1_000);
    assert!(b.receive().is_empty());
    b.write_all(b"kept").unwrap();
    fa.0.inner().set_time(2_000);
    assert!(fa.read_ready().unwrap());
    let mut buf = [0u8; 8];
    assert_eq!(fa.read(&mut buf).unwrap(), 4);
    assert_eq!(&buf[..4], b"kept");
}

#[test]
fn bad_settings_are_refused() {
    assert!(link(&LinkConfig { baud: 0, ..Default::default() }).is_err());
    assert!(link(&LinkConfig { a_to_b: FaultConfig::ber(1.5), ..Default::default() }).is_err());
    assert!(link(&LinkConfig { b_to_a: FaultConfig::ber(f64::NAN), ..Default::default() }).is_err());
}

#[test]
fn overflow_is_counted_not_blocking() {
    let (mut a, _b) = link(&LinkConfig { tx_capacity: 10, ..Default::default() }).unwrap();
    assert_eq!(a.write(&[1u8; 25]).unwrap(), 25);
    let st = a.tx_stats();
    assert_eq!((st.sent, st.overflow, st.in_flight), (10, 15, 10));
}
