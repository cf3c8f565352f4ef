//! The fused pair's routines in Rust, step for step as the assembly, off the Cortex-M4.

use super::{Conv4Job, Px4Job, BLOCK, C, STRIDE};
use crate::decoder::arm::smlad;

/// SXTB16 of `w` rotated right by `rot` bits.
fn sxtb16(w: u32, rot: u32) -> u32 {
    let v = w.rotate_right(rot);
    (v as u8 as i8 as i16 as u16 as u32) | ((((v >> 16) as u8 as i8 as i16) as u16 as u32) << 16)
}

/// The tanh step as the assembly does it (`SHADD16` when k1).
unsafe fn tanh(job: &Px4Job, acc: i32) -> i16 {
    let i = (acc >> job.sh).clamp(-4096, 4095);
    // SAFETY: the table's centre, i within its half-length.
    let y = unsafe { *job.table.offset(i as isize) } as i32;
    let r = if job.k1 != 0 {
        (y + 1) >> 1
    } else {
        (y + job.rnd as i32) >> job.k
    };
    r as i16
}

pub(super) unsafe fn msr_dense_px4(job: *const Px4Job) {
    let j = unsafe { &*job };
    let (mut y, mut b, mut w) = (j.y, j.bias, j.w);
    let mut y_end = j.y_end;
    for row in 0..j.rows {
        if row > 0 {
            unsafe {
                y = (y as *mut u8).add(j.skip as usize) as *mut i16;
                y_end = y_end.add(STRIDE * C);
            }
        }
        unsafe { px4_row(j, &mut y, y_end, &mut b, &mut w) };
    }
}

/// One image row of `msr_dense_px4`.
unsafe fn px4_row(
    j: &Px4Job,
    yp: &mut *mut i16,
    y_end: *mut i16,
    bp: &mut *const i32,
    wp: &mut *const u32,
) {
    let (mut y, mut b, mut w) = (*yp, *bp, *wp);
    while y != y_end {
        let mut acc = [0i32; C];
        for (c, a) in acc.iter_mut().enumerate() {
            *a = unsafe { *b.add(c) };
        }
        for g in 0..j.groups as usize {
            let x = unsafe { core::slice::from_raw_parts(j.x.add(g * BLOCK / 2), 4) };
            for a in acc.iter_mut() {
                if j.i8w != 0 {
                    // Two words of four i8 against (x0, x2), (x1, x3), (x4, x6), (x5, x7).
                    for t in 0..2 {
                        let wv = unsafe { *w.add(t) };
                        *a = smlad(sxtb16(wv, 0), x[2 * t], *a);
                        *a = smlad(sxtb16(wv, 8), x[2 * t + 1], *a);
                    }
                    w = unsafe { w.add(2) };
                } else {
                    for (t, &xv) in x.iter().enumerate() {
                        *a = smlad(unsafe { *w.add(t) }, xv, *a);
                    }
                    w = unsafe { w.add(BLOCK / 2) };
                }
            }
        }
        for (c, &a) in acc.iter().enumerate() {
            unsafe { *y.add(c) = tanh(j, a) };
        }
        unsafe {
            y = y.add(C);
            b = b.add(C);
        }
    }
    (*yp, *bp, *wp) = (y, b, w);
}

pub(super) unsafe fn msr_convt4_grey(job: *const Conv4Job) {
    unsafe { convt4(&*job, false) }
}

pub(super) unsafe fn msr_convt4_grey_room(job: *const Conv4Job) {
    unsafe { convt4(&*job, true) }
}

unsafe fn convt4(j: &Conv4Job, room: bool) {
    let (mut x_row, mut y_row) = (j.x, j.y);
    let (mut w, mut w_other) = (j.w, j.w_other);
    let mut steps = j.x_steps;
    for row in 0..j.rows {
        if row > 0 {
            unsafe {
                x_row = (x_row as *const u8).add(steps[0] as usize) as *const u32;
                y_row = (y_row as *mut u8).add(j.y_step as usize) as *mut i16;
            }
            (w, w_other) = (w_other, w);
            steps = [steps[1], steps[0]];
        }
        let w = unsafe { core::slice::from_raw_parts(w, 16) };
        unsafe { conv4_row(j, x_row, y_row, w, room) };
    }
}

/// One output row of `msr_convt4_grey` (with the room's offsets: `_room`).
unsafe fn conv4_row(j: &Conv4Job, x: *const u32, y: *mut i16, w: &[u32], room: bool) {
    let (mut x, mut y) = (x, y);
    for g in 0..j.groups as usize {
        let mut acc = [j.bias; 4];
        for row in 0..2 {
            let xr = unsafe { x.add(row * STRIDE * 2) };
            for (s, a) in acc.iter_mut().enumerate() {
                let (d, ws) = ([0, 1, 1, 2][s], &w[row * 8 + (s % 2) * 4..][..4]);
                for t in 0..4 {
                    *a = smlad(unsafe { *xr.add(2 * d + t) }, ws[t], *a);
                }
            }
        }
        for a in acc {
            let i = (a >> j.sh).clamp(-4096, 4095);
            // SAFETY: the table's centre, i within its half-length.
            let t = unsafe { *j.table.offset(i as isize) } as i32;
            let mut v = (32640 + t - (t >> 8)) as u16;
            if room {
                // SAFETY: the caller's entry for every group of the row.
                v = unsafe { *j.room.add(g) }.add_to(v);
            }
            unsafe {
                *y = v as i16;
                y = y.add(1);
            }
        }
        x = unsafe { x.add(4) };
    }
}
