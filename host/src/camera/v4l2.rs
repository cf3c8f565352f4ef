//! V4L2 cameras (`--camera /dev/videoN`): the capture formats this takes and their conversion
//! to grey, and (with the `v4l` feature, Linux) a [`FrameSource`] on the `v4l` crate.
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
    Grey,
    Yuyv,
    Uyvy,
}

impl PixelFormat {
    pub fn from_fourcc(f: &[u8; 4]) -> Option<PixelFormat> {
        match f {
            b"GREY" => Some(PixelFormat::Grey),
            b"YUYV" => Some(PixelFormat::Yuyv),
            b"UYVY" => Some(PixelFormat::Uyvy),
            _ => None,
        }
    }

    pub fn fourcc(self) -> [u8; 4] {
        match self {
            PixelFormat::Grey => *b"GREY",
            PixelFormat::Yuyv => *b"YUYV",
            PixelFormat::Uyvy => *b"UYVY",
        }
    }

    fn bytes_per_pixel(self) -> usize {
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

#[cfg(feature = "v4l")]
pub use device::V4lSource;

#[cfg(feature = "v4l")]
mod device {
    use super::{to_grey, PixelFormat};
    use crate::camera::{Frame, FrameSource};
    use anyhow::{anyhow, bail, Context, Result};
    use std::path::Path;
    use std::time::Duration;
    use v4l::buffer::Type;
    use v4l::io::mmap::Stream;
    use v4l::io::traits::CaptureStream;
    use v4l::video::Capture;

    /// A V4L2 camera, memory-mapped streaming, asked for grey (or YUYV/UYVY) at a size and rate.
    pub struct V4lSource {
        stream: Stream<'static>,
        format: PixelFormat,
        width: u32,
        height: u32,
        stride: u32,
        name: String,
        n: u64,
    }

    impl V4lSource {
        pub fn open(path: &Path, size: [u32; 2], fps: f64, timeout: Duration) -> Result<V4lSource> {
            let name = path.display().to_string();
            let dev = v4l::Device::with_path(path).with_context(|| format!("opening camera {name}"))?;
            let mut got = None;
            for want in [PixelFormat::Grey, PixelFormat::Yuyv, PixelFormat::Uyvy] {
                let mut f = dev.format().with_context(|| format!("{name}: reading its format"))?;
                f.width = size[0];
                f.height = size[1];
                f.fourcc = v4l::FourCC::new(&want.fourcc());
                let f = dev.set_format(&f).with_context(|| format!("{name}: setting its format"))?;
                if let Some(p) = PixelFormat::from_fourcc(&f.fourcc.repr) {
                    got = Some((p, f));
                    break;
                }
            }
            let (format, f) = got.ok_or_else(|| anyhow!("{name} offers none of GREY, YUYV, UYVY"))?;
            if fps > 0.0 {
                let p = v4l::video::capture::Parameters::with_fps(fps.round().max(1.0) as u32);
                let _ = dev.set_params(&p); // a camera of a fixed rate keeps its own
            }
            let mut stream = Stream::with_buffers(&dev, Type::VideoCapture, 4)
                .with_context(|| format!("{name}: starting to stream"))?;
            stream.set_timeout(timeout);
            if f.width == 0 || f.height == 0 {
                bail!("{name}: the driver set an empty format");
            }
            Ok(V4lSource { stream, format, width: f.width, height: f.height, stride: f.stride, name, n: 0 })
        }
    }

    impl FrameSource for V4lSource {
        fn next_frame(&mut self) -> Result<Option<Frame>> {
            let (buf, meta) = CaptureStream::next(&mut self.stream)
                .with_context(|| format!("{}: no frame (the camera stopped delivering?)", self.name))?;
            let used = (meta.bytesused as usize).min(buf.len());
            let grey = to_grey(&buf[..used], self.format, self.width, self.height, self.stride)
                .with_context(|| format!("{} frame {}", self.name, self.n))?;
            let name = format!("{}-{:06}", self.name, self.n);
            self.n += 1;
            Ok(Some(Frame { name, grey }))
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

    #[test]
    fn fourccs() {
        assert_eq!(PixelFormat::from_fourcc(b"YUYV"), Some(PixelFormat::Yuyv));
        assert_eq!(PixelFormat::from_fourcc(b"MJPG"), None);
        for f in [PixelFormat::Grey, PixelFormat::Yuyv, PixelFormat::Uyvy] {
            assert_eq!(PixelFormat::from_fourcc(&f.fourcc()), Some(f));
        }
    }
}
