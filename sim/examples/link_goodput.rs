//! Host-link goodput: face frames streamed back to back (the next one as soon as the board has
//! the last one whole) to the in-process board over the paced 921600 baud link, with bit errors
//! on both directions of both links if asked. Prints face bytes delivered per simulated second.
//!
//! `cargo run --release -p msr-sim --example link_goodput -- MODEL.msrm [SECONDS] [BER] [CHUNK]`
//! (CHUNK: a fixed chunk size instead of the one the line estimate picks).
use msr_firmware::model::RamStore;
use msr_firmware::Board;
use msr_shared::deliver::FaceLink;
use msr_shared::frame::{encode_message_vec, FrameAccumulator, Sequencer, MAX_WIRE_FRAME};
use msr_shared::msg::BoardToHost;
use msr_sim::link::{FaultConfig, LinkEnd};
use msr_sim::world::{self, Flow, World, WorldConfig};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let Some(path) = args.get(1) else {
        eprintln!("usage: link_goodput MODEL.msrm [SECONDS] [BER] [CHUNK]");
        std::process::exit(2);
    };
    let bytes = std::fs::read(path).expect("reading the model");
    let secs: f64 = args.get(2).map_or(5.0, |s| s.parse().expect("seconds"));
    let ber: f64 = args.get(3).map_or(0.0, |s| s.parse().expect("BER"));
    let fixed: Option<u16> = args.get(4).map(|s| s.parse().expect("chunk"));
    // The board wants its blob 4-byte aligned: keep it in words.
    let words: Vec<u32> = bytes
        .chunks(4)
        .map(|c| {
            let mut w = [0u8; 4];
            w[..c.len()].copy_from_slice(c);
            u32::from_le_bytes(w)
        })
        .collect();
    let words: &'static [u32] = Box::leak(words.into_boxed_slice());
    let blob: &'static [u8] = &bytemuck::cast_slice(words)[..bytes.len()];
    let m = msr_shared::blob::Model::parse(blob).expect("a model blob");
    let size = [m.face_w, m.face_h];
    let n = m.face_w as usize * m.face_h as usize;
    let mut board = Box::new(Board::new(RamStore::<4>::new(Some(blob))));
    let px: Vec<u8> = (0..n).map(|i| (i * 7 % 251) as u8).collect();
    let mut cfg = WorldConfig::default();
    for f in [&mut cfg.host_link.a_to_b, &mut cfg.host_link.b_to_a, &mut cfg.servo_link.a_to_b, &mut cfg.servo_link.b_to_a] {
        *f = FaultConfig::ber(ber);
    }
    let mut link = FaceLink::new(4000);
    link.fixed_chunk = fixed;
    let mut seq = Sequencer::default();
    let mut rx = FrameAccumulator::<MAX_WIRE_FRAME>::new();
    let max_us = (secs * 1e6) as u64;
    {
        let mut fw = |now: u64, h: &mut LinkEnd, s: &mut LinkEnd| board.poll(now, h, s);
        world::run(
            &cfg,
            &mut fw,
            |w: &mut World| {
                for b in w.host.receive() {
                    if let Some(Ok(f)) = rx.push(b) {
                        if let Ok(msg) = f.message::<BoardToHost>() {
                            link.on_message(&msg);
                        }
                    }
                }
                if link.in_flight_since().is_none() {
                    link.start([10, 10], size, px.clone(), w.now_us);
                }
                link.check(w.now_us);
                let mut out = Vec::new();
                link.pump(|m| out.extend(encode_message_vec(seq.next(), m).expect("fits")));
                w.host.send(&out);
                link.sent(w.host.tx_idle_at_us());
                Flow::Continue
            },
            max_us,
        )
        .expect("run");
    }
    let s = link.stats;
    let st = board.status();
    println!(
        "protocol 2, BER {ber:e}: {} frames of {n} bytes in {secs} s at 921600 baud: goodput {:.0} B/s; \
         chunks sent {}, resent {}, polls {}, timeouts {}, superseded {}; board: {} frames, {} image CRC errors; \
         chunk now {}",
        s.delivered,
        s.face_bytes as f64 / secs,
        s.chunks_sent,
        s.chunks_resent,
        s.polls,
        s.timeouts,
        s.superseded,
        st.frames,
        st.frame_crc_errors,
        link.fixed_chunk.unwrap_or_else(|| link.estimate.chunk()),
    );
}
