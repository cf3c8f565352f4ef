//! The store against power cuts, as MCUboot's simulator and sequential-storage test theirs: an
//! emulated F429 bank (its sector map, byte programming, no program without erase, torn
//! programs and erases), power cut at every program and erase of an upload and of statistics
//! saves, and at a random byte inside each; then a boot, which must run the old or the new
//! model, whole and valid, never neither, never a mix.

use super::emu::{Cut, EmuError, EmuFlash};
use super::*;
use crate::model::{validate, ModelStore, Upload};
use crate::testkit::{mlp_spec, Lcg};
use embedded_storage::nor_flash::{NorFlash, ReadNorFlash};
use std::sync::OnceLock;

type Flash = EmuFlash<Vec<u8>, 1>;
type Store = FlashStore<Flash>;

fn blank() -> Flash {
    EmuFlash::new(vec![0xFF; F429_BANK2.len() as usize], &F429_BANK_SECTORS)
}

/// Model blobs: a small one (two 16 KiB sectors) and one over several sectors of each size.
fn blobs() -> &'static [Vec<u8>; 4] {
    static B: OnceLock<[Vec<u8>; 4]> = OnceLock::new();
    B.get_or_init(|| {
        [
            mlp_spec(1, 24, 20).to_bytes().unwrap(),
            mlp_spec(2, 24, 20).to_bytes().unwrap(),
            mlp_spec(3, 58, 75).to_bytes().unwrap(),
            mlp_spec(4, 58, 75).to_bytes().unwrap(),
        ]
    })
}

fn builtin() -> &'static [u8] {
    static B: OnceLock<Vec<u8>> = OnceLock::new();
    B.get_or_init(|| mlp_spec(9, 24, 20).to_bytes().unwrap())
}

fn boot(flash: Flash, with_builtin: bool) -> Store {
    let mut s = FlashStore::new(flash, F429_BANK2, with_builtin.then(builtin));
    s.start();
    s
}

/// An upload as the board runs it: begin, the erase in steps, chunks of 224 bytes, commit.
fn upload(store: &mut Store, blob: &[u8]) -> bool {
    let mut up = Upload::new();
    if up.begin(store, blob.len() as u32, CRC32.checksum(blob)).is_err() {
        return false;
    }
    let mut steps = 0;
    while store.busy() {
        store.step();
        steps += 1;
        assert!(steps < 100, "the erase does not end");
    }
    for (i, c) in blob.chunks(224).enumerate() {
        if up.chunk(store, (i * 224) as u32, c).is_err() {
            return false;
        }
    }
    up.commit(store).is_ok()
}

/// Saves until the save goes through (a compaction first, in steps), as a board retries.
fn save(store: &mut Store, crc: u32, now: u64, bytes: &[u8]) -> bool {
    for _ in 0..100 {
        match store.save_stats(crc, now, bytes) {
            Ok(()) => return true,
            Err(StatsError::Busy) => store.step(),
            Err(_) => return false,
        }
    }
    false
}

fn stats_bytes(i: u32) -> Vec<u8> {
    let mut r = Lcg(i as u64 + 77);
    (0..(1000 + i * 613) % 4000).map(|_| r.next_u32() as u8).collect()
}

fn model_crc(b: &[u8]) -> u32 {
    validate(b).unwrap().crc32
}

/// The model a booted store runs, checked whole: `Some(blob)` from `choices`.
fn running<'a>(s: &Store, choices: &[&'a [u8]], what: &str) -> &'a [u8] {
    let active = s.active().unwrap_or_else(|| panic!("{what}: no model"));
    let hit = choices.iter().find(|c| **c == active).unwrap_or_else(|| {
        panic!("{what}: runs {} bytes that are none of the expected models", active.len())
    });
    validate(active).unwrap_or_else(|e| panic!("{what}: the running model does not validate: {e:?}"));
    hit
}

/// Cut points of an operation with `ops` flash operations: at the start of each, at a random
/// byte inside it, and right after it.
fn cuts(ops: u32, rng: &mut Lcg) -> Vec<Cut> {
    let mut v = Vec::new();
    for op in 0..ops {
        v.push(Cut { op, byte: 0, inside: false });
        v.push(Cut { op, byte: rng.next_u32(), inside: true });
        v.push(Cut { op, byte: u32::MAX, inside: false });
    }
    v
}

/// Runs `op` on a store booted from `start` with power cut at every cut point, boots again and
/// hands the store and whether `op` finished to `check`. Every 8th cut the board then uploads
/// another model, which must go through and run (the store is not stuck). Returns the count.
fn every_cut(
    start: &Flash,
    with_builtin: bool,
    op: impl Fn(&mut Store) -> bool,
    check: impl Fn(&Store, bool, &str),
) -> usize {
    // A clean run: it must finish, and counts the operations.
    let mut s = boot(clone(start), with_builtin);
    s.flash_mut().cut_at(Cut { op: u32::MAX, byte: 0, inside: false }, 0);
    assert!(op(&mut s), "the operation fails without a power cut");
    let ops = s.flash().ops;
    check(&boot(s.into_flash(), with_builtin), true, "no cut");
    let mut rng = Lcg(ops as u64);
    let all = cuts(ops, &mut rng);
    for (i, cut) in all.iter().enumerate() {
        let mut s = boot(clone(start), with_builtin);
        s.flash_mut().cut_at(*cut, rng.next_u32() as u64);
        let done = op(&mut s);
        let mut flash = s.into_flash();
        assert!(done || flash.is_off(), "{cut:?}: failed with the power on");
        flash.power_on();
        let what = format!("cut {cut:?} of {ops} operations");
        let s = boot(flash, with_builtin);
        check(&s, done, &what);
        if i % 8 == 0 {
            let mut s = s;
            let next = &blobs()[(i / 8) % 2];
            assert!(upload(&mut s, next), "{what}: the next upload fails");
            let s = boot(s.into_flash(), with_builtin);
            assert_eq!(s.active(), Some(next.as_slice()), "{what}: the next upload does not run");
        }
    }
    all.len()
}

fn clone(f: &Flash) -> Flash {
    EmuFlash::new(f.cells().clone(), &F429_BANK_SECTORS)
}

/// A flash whose store ran `setup`.
fn prepared(with_builtin: bool, setup: impl FnOnce(&mut Store)) -> Flash {
    let mut s = boot(blank(), with_builtin);
    setup(&mut s);
    s.into_flash()
}

thread_local! {
    static LAST: std::cell::Cell<u32> = const { std::cell::Cell::new(0) };
}

#[test]
fn power_cuts_during_uploads_leave_the_old_or_the_new_model() {
    let b = blobs();
    let mut total = 0;
    // The built-in model, then the first upload.
    let start = prepared(true, |_| {});
    total += every_cut(&start, true, |s| upload(s, &b[0]), |s, done, what| {
        let got = running(s, &[builtin(), &b[0]], what);
        assert!(!done || got == b[0].as_slice(), "{what}: the upload finished but does not run");
    });
    // No built-in model: never none once an upload finished.
    let start = prepared(false, |s| assert!(upload(s, &b[0])));
    total += every_cut(&start, false, |s| upload(s, &b[2]), |s, done, what| {
        let got = running(s, &[&b[0], &b[2]], what);
        assert!(!done || got == b[2].as_slice(), "{what}");
    });
    // Slot 1 running, slot 0 holding an older model: the upload goes over the older one, which
    // must never come back.
    let start = prepared(false, |s| {
        assert!(upload(s, &b[2]));
        assert!(upload(s, &b[1]));
    });
    total += every_cut(&start, false, |s| upload(s, &b[3]), |s, done, what| {
        let got = running(s, &[&b[1], &b[3]], what);
        assert!(!done || got == b[3].as_slice(), "{what}");
    });
    // A log nearly full of statistics: the upload compacts it first.
    let start = prepared(false, |s| {
        assert!(upload(s, &b[0]));
        // Saves until the next one would need a compaction: the upload's begin starts it.
        let mut i = 0;
        while !s.log_low() {
            assert!(save(s, model_crc(&b[0]), i, &stats_bytes(i as u32)));
            i += 1;
        }
        assert!(s.busy(), "no compaction queued");
        LAST.set(i as u32 - 1);
    });
    total += every_cut(&start, false, |s| upload(s, &b[1]), |s, done, what| {
        let got = running(s, &[&b[0], &b[1]], what);
        assert!(!done || got == b[1].as_slice(), "{what}");
        if got == b[0].as_slice() {
            // Still the old model: its statistics are still there.
            let st = s.load_stats(model_crc(&b[0])).unwrap_or_else(|| panic!("{what}: statistics lost"));
            assert_eq!(st.bytes, stats_bytes(LAST.get()).as_slice(), "{what}");
        }
    });
    println!("power cuts during uploads: {total} cut points, each followed by a boot");
    assert!(total > 1000);
}

#[test]
fn power_cuts_during_statistics_saves_keep_the_model_and_whole_statistics() {
    let b = blobs();
    let crc = model_crc(&b[2]);
    let start = prepared(false, |s| {
        assert!(upload(s, &b[2]));
        assert!(save(s, crc, 5, &stats_bytes(0)));
    });
    // Forty saves (the log is compacted on the way, each fourth save or so), then a reset.
    let n = 40;
    let record = std::cell::Cell::new(0u32);
    let count = every_cut(
        &start,
        false,
        |s| {
            record.set(0);
            for i in 1..=n {
                if !save(s, crc, 1000 + i as u64, &stats_bytes(i)) {
                    return false;
                }
                record.set(i);
                s.step();
            }
            let ok = s.reset_stats(crc).is_ok() || {
                s.step();
                s.reset_stats(crc).is_ok()
            };
            if ok {
                record.set(n + 1);
            }
            ok
        },
        |s, done, what| {
            running(s, &[&b[2]], what);
            let last = record.get();
            let got = s.load_stats(crc);
            if done {
                assert!(got.is_none(), "{what}: statistics after their reset");
                return;
            }
            // The last save that finished, or the one in progress (or the reset after it).
            let ok = |i: u32| match (i, got) {
                (i, None) => i == n + 1,
                (i, Some(st)) if i <= n => st.bytes == stats_bytes(i).as_slice() && st.age.saved_ms == if i == 0 { 5 } else { 1000 + i as u64 },
                _ => false,
            };
            assert!(ok(last) || ok(last + 1), "{what}: statistics {:?} bytes after save {last}", got.map(|g| g.bytes.len()));
            // And they stay through the next compactions (each erases a half).
            let before = got.map(|g| g.bytes.to_vec());
            let mut t = boot(clone(s.flash()), false);
            for _ in 0..2 {
                t.want_compaction();
                while t.busy() {
                    t.step();
                }
            }
            let t = boot(t.into_flash(), false);
            running(&t, &[&b[2]], what);
            assert_eq!(t.load_stats(crc).map(|g| g.bytes.to_vec()), before, "{what}: lost in the compactions after");
        },
    );
    println!("power cuts during statistics saves: {count} cut points, each followed by a boot");
    assert!(count > 1000);
}

#[test]
fn the_emulated_flash_is_nor_flash() {
    let mut f = blank();
    // Program only clears bits; a 0 cannot become 1 without an erase.
    f.write(100, &[0xF0]).unwrap();
    f.write(100, &[0x30]).unwrap();
    assert_eq!(f.write(100, &[0x0F]), Err(EmuError::NotErased));
    let mut b = [0u8; 1];
    f.read(100, &mut b).unwrap();
    assert_eq!(b, [0x30]);
    // Erases by whole sectors of the F429's map only.
    assert_eq!(f.erase(0, 8192), Err(EmuError::Bounds));
    assert_eq!(f.erase(16384, 65536 + 16384), Err(EmuError::Bounds));
    f.erase(0, 16384).unwrap();
    assert_eq!(f.mapped()[100], 0xFF);
    f.erase(65536, 131072).unwrap();
    f.erase(131072, 262144).unwrap();
    assert_eq!(F429_BANK2.len(), 1024 * 1024);
    assert_eq!(F429_BANK2.slot_len(0), 480 * 1024);
    assert_eq!(F429_BANK2.slot_len(1), 512 * 1024);
    // A torn program: bytes before the cut written, the rest between old and new; then no power.
    f.cut_at(Cut { op: 1, byte: 3, inside: false }, 7);
    f.write(0, &[0; 8]).unwrap();
    assert_eq!(f.write(16, &[0; 8]), Err(EmuError::PowerCut));
    assert_eq!(&f.mapped()[16..19], &[0, 0, 0]);
    assert!(f.is_off());
    assert_eq!(f.write(32, &[0]), Err(EmuError::PowerCut));
    assert_eq!(f.mapped()[32], 0xFF);
    // A torn erase leaves arbitrary bytes.
    f.power_on();
    f.cut_at(Cut { op: 0, byte: 0, inside: false }, 11);
    assert_eq!(f.erase(16384, 32768), Err(EmuError::PowerCut));
    assert!(f.mapped()[16384..32768].iter().filter(|b| **b != 0xFF).count() > 10_000);
}

#[test]
fn start_up_says_where_the_model_came_from_and_statistics_survive() {
    let b = blobs();
    let s = boot(blank(), false);
    assert_eq!(s.model_source(), ModelSource::None);
    assert_eq!(s.active(), None);
    let s = boot(blank(), true);
    assert_eq!(s.model_source(), ModelSource::BuiltIn);
    let mut s = s;
    assert!(upload(&mut s, &b[0]));
    assert_eq!(s.model_source(), ModelSource::Flash { slot: 0, seq: 1 });
    let crc = model_crc(&b[0]);
    assert!(save(&mut s, crc, 1234, b"room light"));
    let mut s = boot(s.into_flash(), true);
    assert_eq!(s.model_source(), ModelSource::Flash { slot: 0, seq: 1 });
    let st = s.load_stats(crc).unwrap();
    assert_eq!((st.bytes, st.age.saved_ms, st.age.this_boot), (&b"room light"[..], 1234, false));
    assert!(s.load_stats(crc ^ 1).is_none(), "statistics of another model");
    assert!(upload(&mut s, &b[1]));
    assert_eq!(s.model_source(), ModelSource::Flash { slot: 1, seq: 3 });
    assert!(s.load_stats(model_crc(&b[1])).is_none());
    // A damaged slot is not run: the other committed one is.
    let mut flash = s.into_flash();
    let base = F429_BANK2.sector_start(8) as usize;
    let at = (base + 1000..).find(|i| flash.mapped()[*i] != 0).unwrap();
    let v = flash.mapped()[at];
    flash.write(at as u32, &[v & v.wrapping_sub(1)]).unwrap();
    let s = boot(flash, true);
    assert_eq!(s.active(), Some(b[0].as_slice()));
    assert_eq!(s.model_source(), ModelSource::Flash { slot: 0, seq: 1 });
}

#[test]
fn a_bad_upload_leaves_the_model_and_the_next_one_goes() {
    let b = blobs();
    let mut s = boot(blank(), false);
    assert!(upload(&mut s, &b[0]));
    let mut bad = b[1].clone();
    bad[200] ^= 1;
    let mut up = Upload::new();
    up.begin(&mut s, bad.len() as u32, CRC32.checksum(&b[1])).unwrap();
    while s.busy() {
        s.step();
    }
    up.chunk(&mut s, 0, &bad).unwrap();
    assert!(up.commit(&mut s).is_err());
    let mut s = boot(s.into_flash(), false);
    assert_eq!(s.active(), Some(b[0].as_slice()));
    // Larger than the slot it would go to: refused before any erase.
    let mut up = Upload::new();
    assert!(up.begin(&mut s, 600 * 1024, 0).is_err());
    assert!(!s.busy());
    assert!(upload(&mut s, &b[1]));
    assert_eq!(boot(s.into_flash(), false).active(), Some(b[1].as_slice()));
}
