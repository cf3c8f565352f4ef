//! Arbitrary bytes into the Dynamixel Protocol 2.0 receiver: no panic, and every packet it
//! accepts re-encodes (stuffed again, new CRC) to bytes that parse to the same packet; a status
//! gives a position only when it has exactly the four bytes asked for.
#![no_main]
use libfuzzer_sys::fuzz_target;
use msr_shared::dynamixel::{Instruction, Receiver, Status, Writer};

fuzz_target!(|data: &[u8]| {
    let mut rx = Receiver::<256>::new();
    for &b in data {
        rx.push(b);
        while let Some(p) = rx.next_packet() {
            let _ = Instruction::of(&p).sync_entries().count();
            if let Some(s) = Status::of(&p) {
                assert_eq!(s.value(4).is_some(), s.params.len() == 4);
            }
            let (id, instruction, params) = (p.id, p.instruction, p.params.to_vec());
            let mut wire = [0u8; 600];
            let mut w = Writer::new(&mut wire, id, instruction).expect("an accepted ID");
            w.bytes(&params);
            let n = w.finish().expect("an accepted packet fits again");
            let mut again = Receiver::<600>::new();
            let mut got = None;
            for &b in &wire[..n] {
                again.push(b);
                if let Some(q) = again.next_packet() {
                    got = Some((q.id, q.instruction, q.params.to_vec()));
                }
            }
            assert_eq!(got, Some((id, instruction, params)));
        }
    }
});
