//! The benchmark image: runs the pipeline stages on built-in frames and prints, per stage, the
//! emulated instructions per frame (QEMU with `-icount shift=0`), then the memory figures.
//!
//! The model comes built in (`MSR_MODEL_BLOB` at build time) or, without one, over UART0 as
//! `b"MSRB"`, the length (u32 LE) and the blob bytes, into the first flash model slot.
//!
//! Frames are made here from the model itself, so that every stage does real work: the
//! predicted face at a head pose, rounded to grey bytes, with +-2 grey levels of deterministic
//! noise, and on every other frame a 15 x 15 mark of grey 226 (the published test marks).
//! The decoder is timed uncached: the full inference, as the benchmark must report it.
//!
//! After the timed frames, the golden frames (`msr_firmware::golden`: 16 head poses, marks, every
//! stage) give a digest the host compares with its own build's.
//!
//! Output: one line `MSR-BENCH {json}` on the semihosting console, then exit code 0; a bad model
//! prints `MSR-BENCH-ERROR ...` and exits with 1.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use cortex_m_semihosting::hprintln;
use msr_firmware::pipeline::Workspace;
use msr_firmware::reach;
use msr_firmware::saliency::Settings;
use msr_qemu::clock::Clock;
use msr_qemu::exit::exit;
use msr_qemu::uart::{Uart, UART0};
use msr_qemu::{memory, model_area};
use msr_shared::blob::{Model, MAX_FACE_PIXELS};

/// Head poses of the benchmark frames (HeadYaw, HeadPitch), inside the +-5 degree training range.
const POSES: [[f32; 2]; 4] = [[0.0, 0.0], [0.05, -0.03], [-0.07, 0.02], [0.02, 0.06]];
const MARK: usize = 15;
const MARK_GREY: u8 = 226;

static mut WS: Workspace = Workspace::new();
static mut FRAME: [u8; MAX_FACE_PIXELS] = [0; MAX_FACE_PIXELS];

#[derive(Default, Clone, Copy)]
struct Stages {
    decoder: u64,
    saliency: u64,
    blobs: u64,
    reach: u64,
}

#[derive(Default, Clone, Copy)]
struct Line {
    stages: Stages,
    salient: u32,
    components: u32,
    blob: Option<(u32, [u16; 4])>,
    reach: Option<[f32; 5]>,
    /// CRC-32 of the predicted face (u16 little-endian): the host compares it with its own build.
    face_crc: u32,
}

fn read_exact(uart: &mut Uart, buf: &mut [u8]) {
    for b in buf.iter_mut() {
        *b = loop {
            if let Some(x) = uart.try_read() {
                break x;
            }
        };
    }
}

/// The uploaded model, stored in the flash upload area.
fn receive_model() -> &'static [u8] {
    // SAFETY: this image owns UART0.
    let mut uart = unsafe { Uart::new(UART0) };
    let mut head = [0u8; 8];
    read_exact(&mut uart, &mut head);
    if &head[..4] != b"MSRB" {
        hprintln!("MSR-BENCH-ERROR upload does not start with MSRB");
        exit(1);
    }
    let len = u32::from_le_bytes([head[4], head[5], head[6], head[7]]) as usize;
    let area = model_area::bench_area();
    if len > area.len() {
        hprintln!("MSR-BENCH-ERROR model of {} bytes exceeds the {} byte upload area", len, area.len());
        exit(1);
    }
    read_exact(&mut uart, &mut area[..len]);
    &area[..len]
}

/// Deterministic noise in -2..=2 (a 32-bit LCG).
fn noise(state: &mut u32) -> i32 {
    *state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
    ((*state >> 24) % 5) as i32 - 2
}

#[entry]
fn main() -> ! {
    memory::paint_stack();
    let cp = cortex_m::Peripherals::take().unwrap_or_else(|| exit(3));
    let clock = Clock::start(cp.SYST);
    let bytes = if model_area::BUILT_IN.is_empty() { receive_model() } else { model_area::BUILT_IN };
    let model = match Model::parse(bytes) {
        Ok(m) => m,
        Err(e) => {
            hprintln!("MSR-BENCH-ERROR model blob refused: {}", e);
            exit(1);
        }
    };
    // SAFETY: the only references to these statics, taken once in this single-threaded image.
    let (ws, frame) = unsafe { (&mut *core::ptr::addr_of_mut!(WS), &mut *core::ptr::addr_of_mut!(FRAME)) };
    let settings = Settings::of(&model);
    let (h, w) = (model.face_h as usize, model.face_w as usize);
    let n = h * w;
    let frame = &mut frame[..n];
    let mut lines = [Line::default(); POSES.len()];
    let mut rng = 0x1234_5678u32;
    let mut found = 0u32;
    for (k, head) in POSES.iter().enumerate() {
        // The frame: the prediction at this pose, noise, and a mark on even frames.
        let face = match ws.decode(&model, *head) {
            Ok(f) => f,
            Err(e) => {
                hprintln!("MSR-BENCH-ERROR decoder: {}", e);
                exit(1);
            }
        };
        for (p, &q) in frame.iter_mut().zip(face) {
            *p = (((q as i32 + 128) >> 8) + noise(&mut rng)).clamp(0, 255) as u8;
        }
        if k % 2 == 0 && h >= MARK && w >= MARK {
            let (y0, x0) = ((h - MARK) * (k + 1) / 5, (w - MARK) * (4 - k) / 5);
            for y in y0..y0 + MARK {
                frame[y * w + x0..y * w + x0 + MARK].fill(MARK_GREY);
            }
        }
        // Warm the per-model tables once, outside the timing.
        if k == 0 {
            let _ = ws.saliency(&model, &settings, frame);
        }

        let t0 = clock.instructions();
        let decoded = ws.decoder.predict_uncached(&model, *head).is_ok();
        let t1 = clock.instructions();
        let salient = ws.saliency(&model, &settings, frame);
        let t2 = clock.instructions();
        let (blob, summary) = ws.blobs(&model, &settings);
        let t3 = clock.instructions();
        // Reach runs for the winner; without one, for the crop centre, so it is always timed.
        let c = blob.map_or([w as f32 / 2.0, h as f32 / 2.0], |b| b.centroid());
        let r = reach::targets(&model.reach, c);
        let t4 = clock.instructions();
        if !decoded || salient.is_err() {
            hprintln!("MSR-BENCH-ERROR frame {} failed", k);
            exit(1);
        }
        found += blob.is_some() as u32;
        let face_crc = ws.decoder.face().map_or(0, |f| {
            let mut d = msr_shared::blob::CRC32.digest();
            f.iter().for_each(|v| d.update(&v.to_le_bytes()));
            d.finalize()
        });
        lines[k] = Line {
            stages: Stages { decoder: t1 - t0, saliency: t2 - t1, blobs: t3 - t2, reach: t4 - t3 },
            salient: salient.unwrap_or(0),
            components: summary.components,
            blob: blob.map(|b| (b.area, [b.x0, b.y0, b.x1, b.y1])),
            reach: r.map(|x| x.0),
            face_crc,
        };
    }
    // Before anything is printed: formatting takes stack the pipeline does not.
    let stack_peak = memory::stack_peak();
    let golden = match msr_firmware::golden::run(ws, &model, frame) {
        Ok(g) => g,
        Err(e) => {
            hprintln!("MSR-BENCH-ERROR golden frames: {}", e);
            exit(1);
        }
    };
    let room = match msr_firmware::golden::room(ws, &model, frame, || clock.instructions()) {
        Ok(r) => r,
        Err(e) => {
            hprintln!("MSR-BENCH-ERROR room: {}", e);
            exit(1);
        }
    };
    let mut sum = Stages::default();
    for (k, l) in lines.iter().enumerate() {
        let s = l.stages;
        hprintln!(
            "frame {}: decoder {} saliency {} blobs {} reach {} (instructions); salient {} components {} blob {:?} reach {:?}",
            k, s.decoder, s.saliency, s.blobs, s.reach, l.salient, l.components, l.blob, l.reach
        );
        sum.decoder += s.decoder;
        sum.saliency += s.saliency;
        sum.blobs += s.blobs;
        sum.reach += s.reach;
    }
    let f = POSES.len() as u64;
    let sizes = memory::sizes();
    hprintln!(
        "MSR-BENCH {{\"frames\":{},\"marks_found\":{},\"macs\":{},\"stages\":{{\"decoder\":{},\"saliency\":{},\"blobs\":{},\"reach\":{}}},\"static_ram_bytes\":{},\"code_bytes\":{},\"model_bytes\":{},\"model_built_in\":{},\"stack_peak_bytes\":{},\"workspace_bytes\":{},\"face_crc32\":[{},{},{},{}],\"golden_digest\":{},\"golden_detections\":{},\"room\":{{\"learn\":{},\"update\":{},\"apply\":{},\"digest\":{}}}}}",
        f,
        found,
        model.decoder_macs(),
        sum.decoder / f,
        sum.saliency / f,
        sum.blobs / f,
        sum.reach / f,
        sizes.static_ram,
        sizes.code - model_area::BUILT_IN.len(),
        bytes.len(),
        !model_area::BUILT_IN.is_empty(),
        stack_peak,
        core::mem::size_of::<Workspace>(),
        lines[0].face_crc,
        lines[1].face_crc,
        lines[2].face_crc,
        lines[3].face_crc,
        golden.digest,
        golden.detections,
        room.learn,
        room.update,
        room.apply,
        room.digest
    );
    exit(0)
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    hprintln!("MSR-BENCH-ERROR panic: {}", info);
    exit(101)
}
