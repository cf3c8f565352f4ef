//! V4L2 cameras (`/dev/videoN`): the capture formats this takes and their conversion
//! to grey, and (Linux) a `FrameSource` on the pure-Rust `linuxvideo` crate.
//!
//! Formats, as the V4L2 specification lays them out: `GREY` (one byte per pixel, rows of
//! `bytesperline`), `YUYV` (4:2:2 packed, `Y0 Cb Y1 Cr` per two pixels: the Y bytes are the
//! grey frame) and `UYVY` (`Cb Y0 Cr Y1`). Drivers may pad rows, so the stride is the driver's
//! `bytesperline`, not the width.
use anyhow::{bail, Result};
use image::GrayImage;

/// A capture format this converts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PixelFormat {
    /// `GREY`: one byte of luma per pixel.
    Grey,
    /// `YUYV`: 4:2:2 packed, `Y0 Cb Y1 Cr` per two pixels.
    Yuyv,
    /// `UYVY`: 4:2:2 packed, `Cb Y0 Cr Y1` per two pixels.
    Uyvy,
}

impl PixelFormat {
    /// The format a V4L2 four-character code names, `None` for one this does not convert.
    pub fn from_fourcc(f: &[u8; 4]) -> Option<PixelFormat> {
        match f {
            b"GREY" => Some(PixelFormat::Grey),
            b"YUYV" => Some(PixelFormat::Yuyv),
            b"UYVY" => Some(PixelFormat::Uyvy),
            _ => None,
        }
    }

    /// The format's V4L2 four-character code.
    pub fn fourcc(self) -> [u8; 4] {
        match self {
            PixelFormat::Grey => *b"GREY",
            PixelFormat::Yuyv => *b"YUYV",
            PixelFormat::Uyvy => *b"UYVY",
        }
    }

    /// Bytes a pixel takes in a row: 1 for grey, 2 for the 4:2:2 formats.
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            PixelFormat::Grey => 1,
            PixelFormat::Yuyv | PixelFormat::Uyvy => 2,
        }
    }
}

/// One captured buffer as grey: the luma of every pixel. `stride` is the driver's bytes per
/// line; a buffer shorter than the image needs is refused (a driver that delivered a partial
/// frame), never read past.
pub fn to_grey(buf: &[u8], format: PixelFormat, width: u32, height: u32, stride: u32) -> Result<GrayImage> {
    let (w, h, stride) = (width as usize, height as usize, stride as usize);
    let row = w * format.bytes_per_pixel();
    if w == 0 || h == 0 {
        bail!("an empty {width}x{height} frame");
    }
    if matches!(format, PixelFormat::Yuyv | PixelFormat::Uyvy) && w % 2 == 1 {
        bail!("a 4:2:2 frame of odd width {width}");
    }
    if stride < row {
        bail!("bytes per line {stride} is less than a {width}-pixel {format:?} row ({row} bytes)");
    }
    let need = stride * (h - 1) + row;
    if buf.len() < need {
        bail!("a {width}x{height} {format:?} frame needs {need} bytes, the buffer has {}", buf.len());
    }
    let luma_at = match format {
        PixelFormat::Grey => 0,
        PixelFormat::Yuyv => 0,
        PixelFormat::Uyvy => 1,
    };
    let step = format.bytes_per_pixel();
    let mut out = Vec::with_capacity(w * h);
    for y in 0..h {
        let r = &buf[y * stride..y * stride + row];
        out.extend(r.iter().skip(luma_at).step_by(step));
    }
    Ok(GrayImage::from_raw(width, height, out).expect("w * h bytes"))
}

#[cfg(target_os = "linux")]
pub use device::V4lSource;

/// The device side, on the pure-Rust `linuxvideo` crate (plain V4L2 ioctls, no C library).
#[cfg(target_os = "linux")]
mod device {
    use super::{to_grey, PixelFormat};
    use crate::camera::hold::{self, Control, Ctl, Kind};
    use crate::camera::{Frame, FrameSource, Hold};
    use anyhow::{anyhow, bail, Context, Result};
    use linuxvideo::controls::{Cid, ControlFlags, CtrlType};
    use linuxvideo::format::{PixFormat, PixelFormat as FourCc};
    use linuxvideo::stream::ReadStream;
    use linuxvideo::{BufType, Device, Fract};
    use std::collections::BTreeMap;
    use std::os::fd::AsRawFd;
    use std::path::Path;
    use std::time::{Duration, Instant};

    pub(crate) fn cid(c: Ctl) -> Cid {
        match c {
            Ctl::ExposureAuto => Cid::EXPOSURE_AUTO,
            Ctl::ExposureAbsolute => Cid::EXPOSURE_ABSOLUTE,
            Ctl::Autogain => Cid::AUTOGAIN,
            Ctl::Gain => Cid::GAIN,
            Ctl::AutoWhiteBalance => Cid::AUTO_WHITE_BALANCE,
            Ctl::WhiteBalanceTemperature => Cid::WHITE_BALANCE_TEMPERATURE,
        }
    }

    pub(crate) fn ctl_of(id: Cid) -> Option<Ctl> {
        Ctl::ALL.into_iter().find(|c| cid(*c) == id)
    }

    /// A V4L2 camera: memory-mapped streaming, grey (or YUYV/UYVY) at a size and rate, a frame
    /// timeout, and its automatics held once the picture settled ([`Hold`]).
    pub struct V4lSource {
        stream: ReadStream,
        /// A second handle on the device, for its controls (the first became the stream).
        controls: Device,
        format: PixelFormat,
        width: u32,
        height: u32,
        stride: u32,
        name: String,
        n: u64,
        timeout: Duration,
        held: Option<BTreeMap<String, i32>>,
    }

    impl V4lSource {
        /// Opens the camera at `path` in the first of GREY, YUYV, UYVY it offers, at `size`
        /// (width, height) pixels and `fps` frames a second (0: its own rate), waiting at most
        /// `timeout` for a frame, and holds its automatics as `hold` says.
        pub fn open(path: &Path, size: [u32; 2], fps: f64, timeout: Duration, hold: &Hold) -> Result<V4lSource> {
            let name = path.display().to_string();
            let dev = Device::open(path).with_context(|| format!("opening camera {name}"))?;
            let controls = Device::open(path).with_context(|| format!("opening camera {name} for its controls"))?;
            let offered = dev
                .formats(BufType::VIDEO_CAPTURE)
                .map(|f| f.map(|f| f.pixel_format().as_fourcc()))
                .collect::<std::io::Result<Vec<_>>>()
                .with_context(|| format!("{name}: listing its capture formats"))?;
            let want = [PixelFormat::Grey, PixelFormat::Yuyv, PixelFormat::Uyvy]
                .into_iter()
                .find(|p| offered.contains(&p.fourcc()))
                .ok_or_else(|| {
                    let list: Vec<String> = offered.iter().map(|f| String::from_utf8_lossy(f).into_owned()).collect();
                    anyhow!(
                        "{name} offers none of GREY, YUYV, UYVY (it offers {}): stream it through ffmpeg \
                         into --frames - instead",
                        list.join(", ")
                    )
                })?;
            let [w, h] = size;
            let cap = dev
                .video_capture(PixFormat::new(w, h, FourCc::from_fourcc(want.fourcc())))
                .with_context(|| format!("{name}: setting the format {w}x{h} {want:?}"))?;
            let f = cap.format();
            let got = f.pixel_format().as_fourcc();
            if PixelFormat::from_fourcc(&got) != Some(want) {
                bail!("{name}: asked for {want:?}, the driver set {}", String::from_utf8_lossy(&got));
            }
            let (width, height, bpl) = (f.width(), f.height(), f.bytes_per_line());
            if width == 0 || height == 0 {
                bail!("{name}: the driver set an empty {width}x{height} format");
            }
            if fps > 0.0 {
                // A camera of a fixed rate keeps its own: said, not an error.
                if let Err(e) = cap.set_frame_interval(Fract::new(1000, (fps * 1000.0).round().max(1.0) as u32)) {
                    eprintln!("camera {name}: keeps its own frame rate ({fps} fps refused: {e})");
                }
            }
            let stride = match bpl {
                0 => width * want.bytes_per_pixel() as u32,
                s => s,
            };
            let stream = cap.into_stream().with_context(|| format!("{name}: starting to stream"))?;
            let mut s = V4lSource { stream, controls, format: want, width, height, stride, name, n: 0, timeout, held: None };
            s.hold(hold)?;
            Ok(s)
        }

        /// Lets the automatics run for the settle frames, then holds exposure, gain and white
        /// balance (see [`hold::plan`]). Nothing here stops the capture: a control the driver
        /// lacks or refuses is one line on stderr.
        fn hold(&mut self, hold: &Hold) -> Result<()> {
            let Hold::Settle { frames, values } = hold else { return Ok(()) };
            for _ in 0..*frames {
                self.next_frame().context("letting the camera's automatic exposure settle")?;
            }
            let say = |line: String| eprintln!("camera {}: {line}", self.name);
            let driver = describe(&self.controls).unwrap_or_else(|e| {
                say(format!("listing its controls failed ({e}): left as they are"));
                Vec::new()
            });
            let values = match values {
                Some(v) => v.clone(),
                None => hold::values_to_read(&driver)
                    .into_iter()
                    .filter_map(|c| match self.controls.read_control_raw(cid(c)) {
                        Ok(v) => Some((c.name().to_string(), v)),
                        Err(e) => {
                            say(format!("reading {} failed ({e})", c.name()));
                            None
                        }
                    })
                    .collect(),
            };
            let plan = hold::plan(&driver, &values);
            for n in &plan.notes {
                say(n.clone());
            }
            let mut held = plan.held.clone();
            for step in &plan.steps {
                for &(c, v) in &step.writes {
                    if let Err(e) = self.controls.write_control_raw(cid(c), v) {
                        say(format!("the driver refused {} = {v} ({e}): {} left as it is", c.name(), step.what));
                        if let Some((last, _)) = step.writes.last() {
                            held.remove(last.name());
                        }
                        break;
                    }
                }
            }
            let list: Vec<String> = held.iter().map(|(k, v)| format!("{k} {v}")).collect();
            say(format!("held after {frames} frames: {}", if list.is_empty() { "nothing".into() } else { list.join(", ") }));
            self.held = Some(held);
            Ok(())
        }

        /// Whether a frame is ready within `wait` (poll(2) on the stream).
        fn ready(&self, wait: Duration) -> std::io::Result<bool> {
            let deadline = Instant::now() + wait;
            loop {
                let mut fd = libc::pollfd { fd: self.stream.as_raw_fd(), events: libc::POLLIN, revents: 0 };
                let ms = deadline.saturating_duration_since(Instant::now()).as_millis().min(i32::MAX as u128) as i32;
                // SAFETY: one valid pollfd, for the length given.
                let r = unsafe { libc::poll(&mut fd, 1, ms) };
                if r >= 0 {
                    return Ok(r > 0);
                }
                let e = std::io::Error::last_os_error();
                if e.kind() != std::io::ErrorKind::Interrupted {
                    return Err(e);
                }
            }
        }
    }

    /// The driver's controls among those [`hold`] cares about.
    fn describe(dev: &Device) -> std::io::Result<Vec<Control>> {
        let mut out = Vec::new();
        for d in dev.controls() {
            let d = d?;
            let Some(ctl) = ctl_of(d.id()) else { continue };
            let t = d.control_type();
            let kind = if t == CtrlType::MENU {
                Kind::Menu(dev.enumerate_menu(&d).filter_map(|m| m.ok().map(|m| m.index() as i32)).collect())
            } else if t == CtrlType::BOOLEAN {
                Kind::Boolean
            } else if t == CtrlType::INTEGER {
                Kind::Integer
            } else {
                continue;
            };
            let read_only = d.flags().contains(ControlFlags::READ_ONLY);
            out.push(Control { ctl, kind, min: d.minimum(), max: d.maximum(), read_only });
        }
        Ok(out)
    }

    impl FrameSource for V4lSource {
        fn next_frame(&mut self) -> Result<Option<Frame>> {
            loop {
                let ready = self.ready(self.timeout).with_context(|| format!("{}: waiting for a frame", self.name))?;
                if !ready {
                    bail!("{}: no frame within {:?} (the camera stopped delivering?)", self.name, self.timeout);
                }
                let (format, w, h, stride) = (self.format, self.width, self.height, self.stride);
                let (bad, grey) = self
                    .stream
                    .dequeue(|b| Ok((b.is_error(), to_grey(&b, format, w, h, stride))))
                    .with_context(|| format!("{}: taking a frame", self.name))?;
                if bad {
                    // The driver flagged the buffer as corrupt: the next frame is taken.
                    continue;
                }
                let grey = grey.with_context(|| format!("{} frame {}", self.name, self.n))?;
                let name = format!("{}-{:06}", self.name, self.n);
                self.n += 1;
                return Ok(Some(Frame { name, grey }));
            }
        }

        fn discard_buffered(&mut self) {
            while matches!(self.ready(Duration::ZERO), Ok(true)) {
                if self.stream.dequeue(|_| Ok(())).is_err() {
                    break;
                }
            }
        }

        fn camera_controls(&self) -> Option<BTreeMap<String, i32>> {
            self.held.clone()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yuyv_as_the_specification_lays_it_out_gives_its_y_bytes() {
        // V4L2_PIX_FMT_YUYV, a 4x4 image: per row Y'00 Cb00 Y'01 Cr00 Y'02 Cb01 Y'03 Cr01.
        let mut buf = Vec::new();
        for r in 0..4u8 {
            let y = |c: u8| 10 * r + c;
            buf.extend([y(0), 128, y(1), 200, y(2), 50, y(3), 60]);
        }
        let g = to_grey(&buf, PixelFormat::Yuyv, 4, 4, 8).unwrap();
        assert_eq!(g.into_raw(), (0..4u8).flat_map(|r| (0..4).map(move |c| 10 * r + c)).collect::<Vec<_>>());
        // UYVY: Cb00 Y'00 Cr00 Y'01 ...
        let uyvy = [128, 1, 200, 2, 128, 3, 200, 4];
        assert_eq!(to_grey(&uyvy, PixelFormat::Uyvy, 4, 1, 8).unwrap().into_raw(), vec![1, 2, 3, 4]);
    }

    #[test]
    fn padded_rows_are_read_by_stride_and_short_buffers_refused() {
        // GREY, 3x2 with rows padded to 4 bytes; the last row needs no padding.
        let buf = [1, 2, 3, 0xEE, 4, 5, 6];
        assert_eq!(to_grey(&buf, PixelFormat::Grey, 3, 2, 4).unwrap().into_raw(), vec![1, 2, 3, 4, 5, 6]);
        let e = to_grey(&buf[..6], PixelFormat::Grey, 3, 2, 4).unwrap_err().to_string();
        assert!(e.contains("needs 7 bytes") && e.contains("has 6"), "{e}");
        // YUYV 2x2 padded to 6 bytes per line.
        let buf = [9, 0, 8, 0, 0xEE, 0xEE, 7, 0, 6, 0];
        assert_eq!(to_grey(&buf, PixelFormat::Yuyv, 2, 2, 6).unwrap().into_raw(), vec![9, 8, 7, 6]);
        assert!(to_grey(&buf, PixelFormat::Yuyv, 2, 2, 3).is_err(), "stride under a row");
        assert!(to_grey(&buf, PixelFormat::Yuyv, 3, 1, 6).is_err(), "odd 4:2:2 width");
        assert!(to_grey(&[], PixelFormat::Grey, 0, 0, 0).is_err());
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn each_held_control_has_its_own_v4l2_id() {
        use crate::camera::hold::Ctl;
        for c in Ctl::ALL {
            assert_eq!(device::ctl_of(device::cid(c)), Some(c), "{c:?}");
        }
        assert_eq!(device::ctl_of(linuxvideo::controls::Cid::BRIGHTNESS), None);
        // The crate's ids are the specification's (v4l2-controls.h), as hold.rs lists them.
        let id = |c: Ctl| -> u32 {
            // SAFETY: `Cid` is a #[repr(transparent)] u32.
            unsafe { std::mem::transmute::<linuxvideo::controls::Cid, u32>(device::cid(c)) }
        };
        let spec = [0x009a_0901, 0x009a_0902, 0x0098_0912, 0x0098_0913, 0x0098_090c, 0x0098_091a];
        assert_eq!(Ctl::ALL.map(id), spec);
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn a_missing_device_or_a_file_that_is_not_one_is_named_in_one_line() {
        use std::path::Path;
        use std::time::Duration;
        let open = |p: &str| {
            V4lSource::open(Path::new(p), [320, 240], 10.0, Duration::from_millis(100), &crate::camera::Hold::default())
                .err()
                .map(|e| format!("{e:#}"))
                .unwrap()
        };
        let e = open("/nonexistent/video0");
        assert!(e.starts_with("opening camera /nonexistent/video0: ") && !e.contains('\n'), "{e}");
        // /dev/null opens but answers no V4L2 ioctl (VIDIOC_QUERYCAP: ENOTTY).
        let e = open("/dev/null");
        assert!(e.starts_with("opening camera /dev/null: ") && !e.contains('\n'), "{e}");
    }

    #[test]
    fn fourccs() {
        assert_eq!(PixelFormat::from_fourcc(b"YUYV"), Some(PixelFormat::Yuyv));
        assert_eq!(PixelFormat::from_fourcc(b"MJPG"), None);
        for f in [PixelFormat::Grey, PixelFormat::Yuyv, PixelFormat::Uyvy] {
            assert_eq!(PixelFormat::from_fourcc(&f.fourcc()), Some(f));
        }
    }
}
