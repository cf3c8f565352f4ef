//! Frames from a YUV4MPEG2 stream (what `ffmpeg -f yuv4mpegpipe` writes), parsed by the `y4m`
//! crate. Grey (`C mono`) and 8-bit YUV 4:2:0 / 4:2:2 / 4:4:4 are taken, the Y plane as the grey
//! frame; a stream that says its range is limited (`XCOLORRANGE=LIMITED`, 16..=235) is stretched
//! to full range, as a grey camera frame is.
//!
//! The stream is read on a thread of its own, at most two frames ahead, so that a stream that
//! stops delivering is noticed after the timeout instead of blocking for ever.
use super::{Frame, FrameSource};
use anyhow::{anyhow, bail, Result};
use image::GrayImage;
use std::cell::{Cell, RefCell};
use std::io::Read;
use std::rc::Rc;
use std::sync::mpsc::{sync_channel, Receiver, RecvTimeoutError, SyncSender};
use std::time::Duration;

/// Largest frame taken, bytes of all planes (a 4096 x 4096 4:4:4 frame is 48 MiB).
pub const MAX_FRAME_BYTES: usize = 64 << 20;

/// A Y4M stream read on its own thread.
pub struct Y4mSource {
    rx: Receiver<Result<Frame>>,
    timeout: Duration,
    what: String,
    delivered: u64,
    ended: bool,
    /// An error met while discarding frames, reported by the next `next_frame`.
    failed: Option<anyhow::Error>,
}

impl Y4mSource {
    /// Starts reading `reader` (named `what` in errors and frame names).
    pub fn spawn<R: Read + Send + 'static>(reader: R, what: &str, timeout: Duration) -> Y4mSource {
        let (tx, rx) = sync_channel(2);
        let name = what.to_string();
        let spawned = std::thread::Builder::new()
            .name(format!("y4m-{what}"))
            .spawn(move || decode(reader, &name, &tx));
        if let Err(e) = spawned {
            let (tx, rx2) = sync_channel(1);
            let _ = tx.send(Err(anyhow!("cannot start the Y4M reader: {e}")));
            return Y4mSource { rx: rx2, timeout, what: what.into(), delivered: 0, ended: false, failed: None };
        }
        Y4mSource { rx, timeout, what: what.into(), delivered: 0, ended: false, failed: None }
    }
}

impl FrameSource for Y4mSource {
    fn next_frame(&mut self) -> Result<Option<Frame>> {
        if let Some(e) = self.failed.take() {
            self.ended = true;
            return Err(e);
        }
        if self.ended {
            return Ok(None);
        }
        match self.rx.recv_timeout(self.timeout) {
            Ok(Ok(f)) => {
                self.delivered += 1;
                Ok(Some(f))
            }
            Ok(Err(e)) => {
                self.ended = true;
                Err(e)
            }
            Err(RecvTimeoutError::Disconnected) => {
                self.ended = true;
                Ok(None)
            }
            Err(RecvTimeoutError::Timeout) => bail!(
                "the Y4M stream on {} delivered no frame for {:.1} s (after {} frames)",
                self.what,
                self.timeout.as_secs_f64(),
                self.delivered
            ),
        }
    }

    /// Frames read ahead and not yet taken are dropped (an error stays to be reported).
    fn discard_buffered(&mut self) {
        while let Ok(r) = self.rx.try_recv() {
            if let Err(e) = r {
                self.failed = Some(e);
                break;
            }
        }
    }
}

/// Counts what the decoder takes and keeps the stream's first bytes (its header, for errors).
struct Tap<R> {
    inner: R,
    taken: Rc<Cell<u64>>,
    head: Rc<RefCell<Vec<u8>>>,
}

impl<R: Read> Read for Tap<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.taken.set(self.taken.get() + n as u64);
        let mut head = self.head.borrow_mut();
        let room = 256usize.saturating_sub(head.len()).min(n);
        head.extend_from_slice(&buf[..room]);
        Ok(n)
    }
}

/// The header's value of a parameter (`C` for the colour space), as text.
fn param(header: &[u8], key: u8) -> Option<String> {
    let line = header.split(|&b| b == b'\n').next()?;
    line.split(|&b| b == b' ')
        .skip(1)
        .find(|p| p.first() == Some(&key))
        .map(|p| String::from_utf8_lossy(&p[1..]).into_owned())
}

fn decode<R: Read>(reader: R, what: &str, tx: &SyncSender<Result<Frame>>) {
    let taken = Rc::new(Cell::new(0u64));
    let head = Rc::new(RefCell::new(Vec::new()));
    let tap = Tap {
        inner: std::io::BufReader::with_capacity(1 << 16, reader),
        taken: taken.clone(),
        head: head.clone(),
    };
    let mut d = match ::y4m::Decoder::new_with_limits(tap, ::y4m::Limits { bytes: MAX_FRAME_BYTES }) {
        Ok(d) => d,
        Err(e) => {
            let _ = tx.send(Err(header_error(e, &head.borrow(), taken.get(), what)));
            return;
        }
    };
    let (w, h) = (d.get_width(), d.get_height());
    if let Err(e) = check_colour_space(d.get_colorspace()) {
        let _ = tx.send(Err(anyhow!("{what}: {e}")));
        return;
    }
    let limited = d
        .get_raw_params()
        .split(|&b| b == b' ')
        .any(|p| p.eq_ignore_ascii_case(b"XCOLORRANGE=LIMITED"));
    for i in 0u64.. {
        let before = taken.get();
        let grey = match d.read_frame() {
            Ok(f) => {
                let mut y = f.get_y_plane().to_vec();
                if limited {
                    y.iter_mut().for_each(|v| *v = full_range(*v));
                }
                GrayImage::from_raw(w as u32, h as u32, y)
            }
            Err(::y4m::Error::EOF) if taken.get() == before => return, // closed between frames
            Err(::y4m::Error::EOF) => {
                let _ = tx.send(Err(anyhow!(
                    "{what}: the Y4M stream ended in the middle of frame {i} ({} of {} bytes)",
                    taken.get() - before,
                    frame_bytes(w, h, d.get_colorspace()) + 6
                )));
                return;
            }
            Err(::y4m::Error::ParseError(_)) => {
                let _ = tx.send(Err(anyhow!(
                    "{what}: frame {i} does not start with a FRAME line (not a Y4M stream, or \
                     bytes were lost)"
                )));
                return;
            }
            Err(e) => {
                let _ = tx.send(Err(anyhow!("{what}: reading frame {i}: {e}")));
                return;
            }
        };
        let Some(grey) = grey else {
            let _ = tx.send(Err(anyhow!("{what}: frame {i}: the Y plane is not {w}x{h}")));
            return;
        };
        if tx.send(Ok(Frame { name: format!("{what}-{i:06}"), grey })).is_err() {
            return; // nobody is reading any more
        }
    }
}

fn frame_bytes(w: usize, h: usize, c: ::y4m::Colorspace) -> usize {
    use ::y4m::Colorspace::*;
    let (cw, ch) = ((w + 1) / 2, (h + 1) / 2);
    match c {
        Cmono => w * h,
        C422 => w * h + 2 * cw * h,
        C444 => 3 * w * h,
        _ => w * h + 2 * cw * ch,
    }
}

fn check_colour_space(c: ::y4m::Colorspace) -> Result<()> {
    if c.get_bit_depth() != 8 {
        bail!(
            "Y4M colour space {c:?} has {}-bit samples; only 8-bit is taken (ffmpeg: -pix_fmt gray)",
            c.get_bit_depth()
        );
    }
    Ok(())
}

/// 16..=235 to 0..=255, rounded.
fn full_range(v: u8) -> u8 {
    let v = (v as i32 - 16).clamp(0, 219);
    ((v * 255 + 109) / 219) as u8
}

fn header_error(e: ::y4m::Error, head: &[u8], taken: u64, what: &str) -> anyhow::Error {
    match e {
        ::y4m::Error::EOF if taken == 0 => anyhow!("{what}: the Y4M stream is empty"),
        ::y4m::Error::EOF => anyhow!("{what}: the Y4M stream ended inside its header"),
        ::y4m::Error::UnknownColorspace => anyhow!(
            "{what}: Y4M colour space C{} is not supported; give mono, 420, 420jpeg, 420paldv, \
             420mpeg2, 422 or 444 (ffmpeg: -pix_fmt gray)",
            param(head, b'C').unwrap_or_default()
        ),
        ::y4m::Error::OutOfMemory => anyhow!(
            "{what}: a Y4M frame of W{} H{} is larger than {} MiB",
            param(head, b'W').unwrap_or_default(),
            param(head, b'H').unwrap_or_default(),
            MAX_FRAME_BYTES >> 20
        ),
        ::y4m::Error::ParseError(_) if !head.starts_with(b"YUV4MPEG2 ") => {
            anyhow!("{what}: not a Y4M stream (it does not start with \"YUV4MPEG2 \")")
        }
        e => anyhow!("{what}: bad Y4M header: {e}"),
    }
}

#[cfg(test)]
mod tests;
