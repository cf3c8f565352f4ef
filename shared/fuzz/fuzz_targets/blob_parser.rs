//! Arbitrary bytes into the blob parser, with the CRC fixed up half of the time so that the
//! validators behind it are reached. No panic; whatever parses has consistent tables.
#![no_main]
use libfuzzer_sys::fuzz_target;
use msr_shared::blob::{set_self_gate, Model, CRC32};

fuzz_target!(|data: &[u8]| {
    let mut bytes = data.to_vec();
    if bytes.len() >= 16 && bytes[0] & 1 == 1 {
        // Magic, version 1 (or 5, whose sections come after the statistics), header length
        // 40, true length, true CRC.
        let version = if bytes[0] & 2 == 2 { 5 } else { 1 };
        bytes[0..8].copy_from_slice(&[b'M', b'S', b'R', b'M', version, 0, 40, 0]);
        let n = bytes.len() as u32;
        bytes[8..12].copy_from_slice(&n.to_le_bytes());
        let crc = CRC32.checksum(&bytes[16..]);
        bytes[12..16].copy_from_slice(&crc.to_le_bytes());
    }
    let parsed = Model::parse(&bytes);
    if let Ok(m) = parsed {
        for l in &m.layers {
            for i in 0..l.weight_count() {
                let _ = l.weight(i);
            }
            for i in 0..l.bias_count() {
                let _ = l.bias(i);
            }
        }
        assert_eq!(m.mu.len(), m.face_pixels());
        assert_eq!(m.sigma.len(), m.face_pixels());
        // Every pose cell (flag bit 5) has both tables, of the face's size.
        if let Some(p) = &m.pose {
            for k in 0..p.grid.len() {
                let (mu, sigma) = p.tables(k).expect("a parsed grid's cell has its tables");
                assert_eq!((mu.len(), sigma.len()), (m.face_pixels(), m.face_pixels()));
            }
            let _ = m.stats_at([0.01, -0.02]);
        }
        // A self gate (either section layout) is valid, and taking it off and putting it back
        // gives a blob that parses to the same gate.
        if let Some(g) = m.self_gate {
            assert!(g.is_valid());
            let plain = set_self_gate(&bytes, None).expect("a parsed blob loses its gate");
            assert_eq!(Model::parse(&plain).map(|p| p.self_gate), Ok(None));
            let again = set_self_gate(&plain, Some(g)).expect("a parsed gate is written back");
            assert_eq!(Model::parse(&again).map(|p| p.self_gate), Ok(Some(g)));
        }
    }
});
