//! The benchmark image: runs the pipeline stages on built-in frames and prints, per stage, the
//! emulated instructions per frame (QEMU with `-icount shift=0`), then the memory figures.
//!
//! The model comes built in (`MSR_MODEL_BLOB` at build time) or preloaded into the PSRAM by the
//! host (`model_area::PRELOAD_ADDR`), and is copied into the first flash model slot. Not over
//! UART0: the emulated UART moves one byte per turn of QEMU's event loop, and the demo's 479 KB
//! model took 16 s of the benchmark's 16.4 (preloaded: 0.26 s in all).
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
use msr_qemu::{memory, model_area};
use msr_shared::blob::Model;
use msr_shared::msg::MAX_FRAME_BYTES;

/// Head poses of the benchmark frames (HeadYaw, HeadPitch), inside the +-5 degree training range.
const POSES: [[f32; 2]; 4] = [[0.0, 0.0], [0.05, -0.03], [-0.07, 0.02], [0.02, 0.06]];
const MARK: usize = 15;
/// The frame floor the widened table is timed with, Q8.8 (4 grey levels; any non-zero floor
/// costs the same).
const WIDEN_PROBE: u16 = 4 * 256;
const MARK_GREY: u8 = 226;

static mut WS: Workspace = Workspace::new();
static mut FRAME: [u8; MAX_FRAME_BYTES] = [0; MAX_FRAME_BYTES];

#[derive(Default, Clone, Copy)]
struct Stages {
    decoder: u64,
    table: u64,
    /// The same table with each sigma widened by a frame floor ([`WIDEN_PROBE`]): what a frame
    /// whose floor changed pays.
    table_widened: u64,
    saliency: u64,
    /// The colour stage (a model with chroma; 0 otherwise).
    chroma: u64,
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

/// Deterministic noise in -2..=2 (a 32-bit LCG).
fn noise(state: &mut u32) -> i32 {
    *state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
    ((*state >> 24) % 5) as i32 - 2
}

/// Buffers of [`pool_agrees`]: faces up to 75 x 7.
const CHECK_PIXELS: usize = 75 * 7;
static mut CHECK: Check = Check {
    frame: [0; CHECK_PIXELS],
    pred: [0; CHECK_PIXELS],
    thr: [0; CHECK_PIXELS],
    mask: [0; CHECK_PIXELS],
    want: [0; CHECK_PIXELS],
    ring: [0; 7 * 75],
};
struct Check {
    frame: [u8; CHECK_PIXELS],
    pred: [u16; CHECK_PIXELS],
    thr: [u16; CHECK_PIXELS],
    mask: [u8; CHECK_PIXELS],
    want: [u8; CHECK_PIXELS],
    ring: [i32; 7 * 75],
}

/// The board's pooled saliency (the assembly row routine) against the window written out
/// ([`pool::reference`], and [`msr_firmware::extent::mark_spread`] for the extent), on random
/// faces of 16 widths, 5 heights and every radius, with clipped pixels, thresholds from 0 to
/// the saturated 65535, predictions over the whole u16 range, half of them through a random
/// photometric fit: the mask, its count and each row's count must be the same.
fn pool_agrees() -> Result<(), &'static str> {
    use msr_firmware::saliency::pool;
    // SAFETY: the only reference to this static, taken once in this single-threaded image.
    let c = unsafe { &mut *core::ptr::addr_of_mut!(CHECK) };
    let mut next = xorshift(0x9e37_79b9);
    for w in [1usize, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 17, 24, 33, 74, 75] {
        for h in [1usize, 2, 4, 5, 7] {
            for r in 0..=msr_shared::blob::MAX_POOL {
                let n = w * h;
                for i in 0..n {
                    c.frame[i] = next() as u8;
                    c.pred[i] = next() as u16;
                    c.thr[i] = match next() % 8 {
                        0 => 0,
                        1 => u16::MAX,
                        _ => (next() % 24_000) as u16,
                    };
                }
                let mut lut = msr_firmware::light::Lut::IDENTITY;
                if next() % 2 == 0 {
                    // Half of those clipped at a plateau's levels besides 0 and 255.
                    let clip = match next() % 3 {
                        0 => [0, 255],
                        1 => [0, 150 + (next() % 106) as u8],
                        _ => [(next() % 60) as u8, 150 + (next() % 106) as u8],
                    };
                    let fit = msr_firmware::light::LightFit {
                        gain: 20_000 + (next() % 180_000) as i32,
                        offset: (next() % 6_000_000) as i32 - 3_000_000,
                        clip,
                        ..msr_firmware::light::LightFit::IDENTITY
                    };
                    fit.lut(&mut lut);
                }
                let (f, p, t) = (&c.frame[..n], &c.pred[..n], &c.thr[..n]);
                let count = pool::reference(f, p, &lut, t, &mut c.want[..n], w, r);
                for extent in [false, true] {
                    c.mask[..n].fill(9);
                    c.ring.fill(-5);
                    let mut rows = [0u16; 8];
                    let got = pool::pooled_one_sided(f, p, &lut, t, &mut c.mask[..n], &mut c.ring, w, r, &mut rows, extent);
                    if got != count {
                        return Err("the pooled count differs");
                    }
                    for y in 0..h {
                        let k = c.want[y * w..y * w + w].iter().filter(|&&m| m != 0).count();
                        if rows[y] as usize != k {
                            return Err("a row's count differs");
                        }
                    }
                    if extent {
                        let mut rows = [u16::MAX; 8];
                        rows.iter_mut().zip(c.want[..n].chunks(w)).for_each(|(r, m)| *r = m.iter().filter(|&&b| b != 0).count() as u16);
                        msr_firmware::extent::mark_spread(f, p, &lut, t, &mut c.want[..n], w, &rows);
                    }
                    if c.mask[..n] != c.want[..n] {
                        return Err(if extent { "the extent differs" } else { "the pooled mask differs" });
                    }
                }
            }
        }
    }
    Ok(())
}

/// The board's threshold table ([`pool::combined_table`], an assembly routine here for a bound
/// on sigma that keeps every `tn` in a halfword) against [`pool::Combine::at`], on 0 to 40 pixels
/// from a word and from a halfword past one, at thresholds from 1e-3 to 255.9, sigmas up to the
/// largest the bound lets through (and the bound itself), mu from 0 to 65535.
fn table_agrees() -> Result<(), &'static str> {
    use msr_firmware::saliency::pool;
    #[repr(C, align(4))]
    struct Words([u16; 48]);
    let (mut sigma, mut mu, mut out) = (Words([0; 48]), Words([0; 48]), Words([0; 48]));
    let mut next = xorshift(0x51ed_270b);
    for t in [1e-3f32, 0.5, 1.0, 2.7, 4.59, 9.9, 255.9] {
        let c = pool::Combine::new(t, msr_shared::blob::Normalisation::StdDev);
        let bound = ((65535.0 / t) as u32).min(32767) as u16;
        for n in 0..=40 {
            for at in [0usize, 1] {
                for i in 0..n {
                    sigma.0[at + i] = if next() % 5 == 0 { bound } else { (next() % (bound as u32 + 1)) as u16 };
                    mu.0[at + i] = match next() % 4 {
                        0 => u16::MAX,
                        _ => next() as u16,
                    };
                }
                out.0.fill(7);
                pool::combined_table(&sigma.0[at..at + n], &mu.0[at..at + n], &c, bound, &mut out.0[at..at + n]);
                for i in 0..n {
                    if out.0[at + i] != c.at(sigma.0[at + i], mu.0[at + i]) {
                        return Err("a threshold differs");
                    }
                }
                if out.0[at + n..].iter().any(|&v| v != 7) {
                    return Err("a threshold past the end was written");
                }
            }
        }
    }
    Ok(())
}

/// The board's clip test ([`msr_firmware::light::any_clipped`], an assembly routine here) against
/// the plain one, on rows of 0 to 19 bytes at every offset from a word, each byte in turn set to
/// each of the clip levels, their neighbours and 0 and 255, among bytes strictly between the
/// levels; for the camera's 0 and 255 and for plateaus' levels.
fn clip_test_agrees() -> Result<(), &'static str> {
    let mut buf = [7u8; 24];
    for (lo, hi) in [(0u8, 255u8), (0, 178), (16, 235), (40, 255), (100, 102)] {
        let lut = msr_firmware::light::Lut { lo, hi, ..msr_firmware::light::Lut::IDENTITY };
        let span = (hi - lo - 1) as usize;
        for len in 0..20 {
            for start in 0..4 {
                for at in 0..len.max(1) {
                    for v in [lo, lo + 1, hi - 1, hi, 0, 255] {
                        buf.fill(((len * 37 + at * 11) % span) as u8 + lo + 1);
                        let row = &mut buf[start..start + len];
                        if let Some(b) = row.get_mut(at) {
                            *b = v;
                        }
                        let want = row.iter().any(|&f| f <= lo || f >= hi);
                        if msr_firmware::light::any_clipped(row, &lut) != want {
                            return Err(if want { "a clipped byte missed" } else { "a clipped byte seen where none is" });
                        }
                    }
                }
            }
        }
    }
    Ok(())
}

/// The room's row routines ([`msr_firmware::room::rows`], assembly here) against their Rust
/// versions: rule 2's sums on rows of 1 to 16 cells at every offset from a word, masks, clip
/// levels of the camera and of plateaus and none left between them, a random table of `v(I)`;
/// rule 4 over faces of every width to 40 and every tail, on predictions over the whole u16 range
/// with offsets over the whole i16 range.
fn room_rows_agree() -> Result<(), &'static str> {
    use msr_firmware::room::{rows, Acc, CELL};
    // SAFETY: the only reference to this static, taken once in this single-threaded image
    // (after `pool_agrees` is done with it).
    let c = unsafe { &mut *core::ptr::addr_of_mut!(CHECK) };
    let mut next = xorshift(0x6a09_e667);
    let mut v = [0u16; 256];
    let (mut got, mut want) = ([Acc::ZERO; 16], [Acc::ZERO; 16]);
    for cells in 1..=16usize {
        for start in 0..4 {
            for (lo, hi) in [(0u32, 255u32), (20, 200), (99, 100), (0, 1)] {
                let n = cells * CELL;
                for i in 0..n {
                    c.frame[start + i] = next() as u8;
                    c.pred[start + i] = next() as u16;
                    c.mask[start + i] = next().is_multiple_of(4) as u8;
                }
                v.iter_mut().for_each(|x| *x = next() as u16);
                for k in 0..cells {
                    got[k] = Acc { sum: next() as i32 >> 8, pred: next() as i32 >> 8, count: next() >> 8 };
                    want[k] = got[k];
                }
                let mut job = rows::GatherJob {
                    frame: c.frame[start..].as_ptr(),
                    pred: c.pred[start..].as_ptr(),
                    mask: c.mask[start..].as_ptr(),
                    v: v.as_ptr(),
                    acc: got.as_mut_ptr(),
                    cells: cells as u32,
                    first: lo + 1,
                    span: hi - lo - 1,
                };
                // SAFETY: `cells` cells behind every pointer (start + 128 <= CHECK_PIXELS).
                unsafe { rows::gather(&job) };
                job.acc = want.as_mut_ptr();
                // SAFETY: as above.
                unsafe { rows::gather_reference(&job) };
                if got != want {
                    return Err("the room's sums differ");
                }
            }
        }
    }
    // Rule 4 over faces 1 to 40 values wide (0 to 5 whole cells and every tail), of as many
    // rows as fit (three rows of cells at most), starting on a word and between two.
    // Two entries a cell (`Room::halves`), the first read: the second random, never read.
    let mut table = [rows::Packed::ZERO; 3 * 12];
    for w in 1..=40usize {
        for start in 0..2 {
            let n = ((CHECK_PIXELS - start) / w).min(3 * CELL);
            for k in table.iter_mut() {
                *k = rows::Packed::of(match next() % 6 {
                    0 => i16::MIN,
                    1 => i16::MAX,
                    2 => 0,
                    _ => next() as i16 >> (next() % 12),
                });
            }
            for i in 0..n * w {
                c.pred[start + i] = next() as u16;
            }
            c.thr[start..start + n * w].copy_from_slice(&c.pred[start..start + n * w]);
            let mut job = rows::ApplyJob {
                pred: c.pred[start..].as_mut_ptr(),
                cells: table.as_ptr(),
                full: (w / CELL) as u32,
                tail: (w % CELL) as u32,
                rows: n as u32,
                stride: (12 * core::mem::size_of::<rows::Packed>()) as u32,
            };
            // SAFETY: `n * w` values behind `pred` (start + n * w <= CHECK_PIXELS); `n` rows
            // need at most 3 rows of cells, `w <= 40` at most 5 cells a row, of 6 (12 entries).
            unsafe { rows::apply(&job) };
            job.pred = c.thr[start..].as_mut_ptr();
            // SAFETY: as above.
            unsafe { rows::apply_reference(&job) };
            if c.pred[start..start + n * w] != c.thr[start..start + n * w] {
                return Err("the room's offsets added differ");
            }
        }
    }
    Ok(())
}

/// Xorshift32 from `seed` (not 0): the checks' random inputs, the same on every run.
fn xorshift(mut seed: u32) -> impl FnMut() -> u32 {
    move || {
        seed ^= seed << 13;
        seed ^= seed >> 17;
        seed ^= seed << 5;
        seed
    }
}

/// The board's sample levels ([`msr_firmware::light::sample_levels`], an assembly routine here)
/// against the plain ones, on 0 to 256 samples of random and of few distinct grey levels.
fn sample_levels_agree() -> Result<(), &'static str> {
    let mut next = xorshift(0x2545_f491);
    let mut xs = [0u8; msr_firmware::light::MAX_SAMPLES];
    for n in 0..=msr_firmware::light::MAX_SAMPLES {
        for spread in [254u32, 3] {
            let base = 1 + next() % (255 - spread);
            for x in xs.iter_mut() {
                *x = (base + next() % (spread + 1)) as u8;
            }
            let want = msr_firmware::light::sample_levels_reference(&xs[..n]);
            if msr_firmware::light::sample_levels(&mut xs, n) != want {
                return Err("the sample levels differ");
            }
        }
    }
    Ok(())
}

/// The board's table of `v(I)` ([`msr_firmware::light::ramp`], an assembly routine here)
/// against the plain loop: gains and offsets at the fit's limits, rising and falling ramps that
/// cross 0 and `V_MAX` anywhere in the table, flat ones, and random ones within the routine's
/// bounds.
fn ramp_agrees() -> Result<(), &'static str> {
    let mut next = xorshift(0x9e37_79b9);
    let (mut got, mut want) = ([0u16; 256], [0u16; 256]);
    let cases = [(128, 65536), (-(1 << 28), 1 << 20), ((1 << 28) + 128, -(1 << 20)), (0, 0), (65280 << 8, 0), (-1, 1), (65281 << 8, -257), (-(1 << 29), 1 << 21)];
    for k in 0..4000u32 {
        let gain = (next() as i32) >> (11 + k % 8);
        let first = ((next() as i32) >> 3).clamp(-(1 << 30) + 1, (1 << 30) - 1);
        let last = first as i64 + 255 * gain as i64;
        if last.abs() >= 1 << 30 {
            continue;
        }
        msr_firmware::light::ramp(&mut got, first, gain);
        msr_firmware::light::ramp_reference(&mut want, first, gain);
        if got != want {
            return Err("the table of v(I) differs on a random ramp");
        }
    }
    for (first, gain) in cases {
        msr_firmware::light::ramp(&mut got, first, gain);
        msr_firmware::light::ramp_reference(&mut want, first, gain);
        if got != want {
            return Err("the table of v(I) differs at a limit");
        }
    }
    Ok(())
}

#[entry]
fn main() -> ! {
    memory::paint_stack();
    let cp = cortex_m::Peripherals::take().unwrap_or_else(|| exit(3));
    let clock = Clock::start(cp.SYST);
    let bytes = if !model_area::BUILT_IN.is_empty() {
        model_area::BUILT_IN
    } else {
        match model_area::preloaded_blob() {
            Ok(Some(blob)) => {
                let area = model_area::bench_area();
                area[..blob.len()].copy_from_slice(blob);
                &area[..blob.len()]
            }
            Ok(None) => {
                hprintln!("MSR-BENCH-ERROR no model: none is built in and none was preloaded");
                exit(1);
            }
            Err(e) => {
                hprintln!("MSR-BENCH-ERROR preloaded model refused: {:?}", e);
                exit(1);
            }
        }
    };
    let model = match Model::parse(bytes) {
        Ok(m) => m,
        Err(e) => {
            hprintln!("MSR-BENCH-ERROR model blob refused: {}", e);
            exit(1);
        }
    };
    // SAFETY: the only references to these statics, taken once in this single-threaded image.
    let (ws, whole) = unsafe { (&mut *core::ptr::addr_of_mut!(WS), &mut *core::ptr::addr_of_mut!(FRAME)) };
    if let Err(e) = pool_agrees() {
        hprintln!("MSR-BENCH-ERROR the pooled saliency: {}", e);
        exit(1);
    }
    if let Err(e) = table_agrees() {
        hprintln!("MSR-BENCH-ERROR the threshold table: {}", e);
        exit(1);
    }
    if let Err(e) = clip_test_agrees() {
        hprintln!("MSR-BENCH-ERROR the clip test: {}", e);
        exit(1);
    }
    if let Err(e) = ramp_agrees() {
        hprintln!("MSR-BENCH-ERROR the table of v(I): {}", e);
        exit(1);
    }
    if let Err(e) = sample_levels_agree() {
        hprintln!("MSR-BENCH-ERROR the sample levels: {}", e);
        exit(1);
    }
    if let Err(e) = room_rows_agree() {
        hprintln!("MSR-BENCH-ERROR the room: {}", e);
        exit(1);
    }
    let settings = Settings::of(&model);
    let (h, w) = (model.face_h as usize, model.face_w as usize);
    let n = h * w;
    let (frame, planes) = whole.split_at_mut(n);
    let planes = &mut planes[..2 * msr_shared::blob::chroma::blocks(h, w)];
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
        // The threshold table of the pose's cell (cached until the head changes cell; each of
        // these poses is in another one), then the frame's own work.
        let tw0 = clock.instructions();
        ws.thresholds.invalidate();
        ws.thresholds.prepare(&model, &settings, *head, WIDEN_PROBE);
        let tw1 = clock.instructions();
        let t1 = clock.instructions();
        ws.thresholds.invalidate();
        ws.thresholds.prepare(&model, &settings, *head, 0);
        let t1t = clock.instructions();
        let salient = ws.saliency(&model, &settings, frame);
        let tc = clock.instructions();
        // Colour: neutral planes with noise, the mark's blocks of another hue (made outside
        // the timing: a camera's frame brings them).
        let coloured = if model.chroma.is_some() {
            let (bh, bw) = (h.div_ceil(2), w.div_ceil(2));
            let nb = bh * bw;
            for (b, p) in planes.iter_mut().enumerate() {
                *p = (128 + noise(&mut rng) / 2) as u8;
                let (by, bx) = ((b % nb) / bw, (b % nb) % bw);
                if k % 2 == 0 && h >= MARK && w >= MARK {
                    let (y0, x0) = ((h - MARK) * (k + 1) / 5 / 2, (w - MARK) * (4 - k) / 5 / 2);
                    if (y0..y0 + MARK / 2).contains(&by) && (x0..x0 + MARK / 2).contains(&bx) {
                        *p = if b < nb { 70 } else { 190 };
                    }
                }
            }
            let tc0 = clock.instructions();
            let r = ws.chroma(&model, frame, planes);
            (clock.instructions() - tc0, r.is_ok())
        } else {
            (0, true)
        };
        let t2 = clock.instructions();
        let (blob, summary) = ws.blobs(&model, &settings);
        let t3 = clock.instructions();
        // Reach runs for the winner; without one, for the crop centre, so it is always timed.
        let c = blob.map_or([w as f32 / 2.0, h as f32 / 2.0], |b| b.centroid());
        let r = reach::targets(&model.reach, c);
        let t4 = clock.instructions();
        if !decoded || salient.is_err() || !coloured.1 {
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
            stages: Stages {
                decoder: tw0 - t0,
                table: t1t - t1,
                table_widened: tw1 - tw0,
                saliency: tc - t1t,
                chroma: coloured.0,
                blobs: t3 - t2,
                reach: t4 - t3,
            },
            salient: salient.unwrap_or(0),
            components: summary.components,
            blob: blob.map(|b| (b.area, [b.x0, b.y0, b.x1, b.y1])),
            reach: r.map(|x| x.0),
            face_crc,
        };
    }
    // Before anything is printed: formatting takes stack the pipeline does not.
    let stack_peak = memory::stack_peak();
    let golden = match msr_firmware::golden::run(ws, &model, whole) {
        Ok(g) => g,
        Err(e) => {
            hprintln!("MSR-BENCH-ERROR golden frames: {}", e);
            exit(1);
        }
    };
    let room = match msr_firmware::golden::room(ws, &model, whole, || clock.instructions()) {
        Ok(r) => r,
        Err(e) => {
            hprintln!("MSR-BENCH-ERROR room: {}", e);
            exit(1);
        }
    };
    let mut sum = Stages::default();
    // The costliest frame after the decoder at a held pose (a marked one: the extent and the
    // blob), and the costliest without a blob (what a frame the room learns from is).
    let (mut held_max, mut held_clear_max) = (0u64, 0u64);
    for (k, l) in lines.iter().enumerate() {
        let s = l.stages;
        held_max = held_max.max(s.saliency + s.chroma + s.blobs + s.reach);
        if l.blob.is_none() {
            held_clear_max = held_clear_max.max(s.saliency + s.chroma + s.blobs + s.reach);
        }
        hprintln!(
            "frame {}: decoder {} table {} saliency {} chroma {} blobs {} reach {} (instructions); salient {} components {} blob {:?} reach {:?}",
            k, s.decoder, s.table, s.saliency, s.chroma, s.blobs, s.reach, l.salient, l.components, l.blob, l.reach
        );
        sum.decoder += s.decoder;
        sum.table += s.table;
        sum.table_widened += s.table_widened;
        sum.saliency += s.saliency;
        sum.chroma += s.chroma;
        sum.blobs += s.blobs;
        sum.reach += s.reach;
    }
    let f = POSES.len() as u64;
    let sizes = memory::sizes();
    hprintln!(
        "MSR-BENCH {{\"frames\":{},\"marks_found\":{},\"macs\":{},\"stages\":{{\"decoder\":{},\"table\":{},\"table_widened\":{},\"saliency\":{},\"chroma\":{},\"blobs\":{},\"reach\":{}}},\"held_max\":{},\"held_clear_max\":{},\"static_ram_bytes\":{},\"code_bytes\":{},\"model_bytes\":{},\"model_built_in\":{},\"stack_peak_bytes\":{},\"workspace_bytes\":{},\"face_crc32\":[{},{},{},{}],\"golden_digest\":{},\"golden_detections\":{},\"room\":{{\"learn\":{},\"update\":{},\"apply\":{},\"digest\":{}}}}}",
        f,
        found,
        model.decoder_macs(),
        sum.decoder / f,
        sum.table / f,
        sum.table_widened / f,
        sum.saliency / f,
        sum.chroma / f,
        sum.blobs / f,
        sum.reach / f,
        held_max,
        held_clear_max,
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
