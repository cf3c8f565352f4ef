//! Literal streams as the YUV4MPEG2 description gives them (a `YUV4MPEG2 ` header line of
//! space-separated parameters, then per frame a `FRAME` line and the planes Y, Cb, Cr).
use super::*;
use std::io::Cursor;

const T: Duration = Duration::from_secs(2);

fn source(bytes: &[u8]) -> Y4mSource {
    Y4mSource::spawn(Cursor::new(bytes.to_vec()), "test", T)
}

fn all(bytes: &[u8]) -> Result<Vec<Vec<u8>>> {
    let mut s = source(bytes);
    let mut out = Vec::new();
    while let Some(f) = s.next_frame()? {
        out.push(f.grey.into_raw());
    }
    Ok(out)
}

fn err(bytes: &[u8]) -> String {
    format!("{:#}", all(bytes).unwrap_err())
}

#[test]
fn mono_frames_are_taken_as_they_are() {
    let mut b = b"YUV4MPEG2 W4 H2 F30:1 Ip A1:1 Cmono\n".to_vec();
    b.extend(b"FRAME\n");
    b.extend([0, 1, 2, 3, 250, 251, 252, 255]);
    b.extend(b"FRAME\n");
    b.extend([9; 8]);
    let frames = all(&b).unwrap();
    assert_eq!(frames, vec![vec![0, 1, 2, 3, 250, 251, 252, 255], vec![9; 8]]);
    let mut s = source(&b);
    let f = s.next_frame().unwrap().unwrap();
    assert_eq!(f.grey.dimensions(), (4, 2));
    assert_eq!(f.name, "test-000000");
}

#[test]
fn the_y_plane_of_420_422_and_444_is_the_grey_frame() {
    let y = [10u8, 20, 30, 40, 50, 60, 70, 80];
    // 4x2: 4:2:0 has 2x1 chroma samples per plane, 4:2:2 2x2, 4:4:4 4x2.
    for (c, chroma) in [("C420jpeg", 2), ("C420", 2), ("C420paldv", 2), ("C420mpeg2", 2), ("C422", 4), ("C444", 8), ("", 2)] {
        let mut b = format!("YUV4MPEG2 W4 H2 F25:1 Ip A0:0 {c}\n").into_bytes();
        for _ in 0..2 {
            b.extend(b"FRAME\n");
            b.extend(y);
            b.extend(vec![128u8; chroma]); // Cb
            b.extend(vec![200u8; chroma]); // Cr
        }
        assert_eq!(all(&b).unwrap(), vec![y.to_vec(), y.to_vec()], "{c}");
    }
    // Odd sizes round the chroma planes up: 3x3 4:2:0 has 2x2 chroma samples.
    let mut b = b"YUV4MPEG2 W3 H3 F25:1 C420jpeg\nFRAME\n".to_vec();
    b.extend([1, 2, 3, 4, 5, 6, 7, 8, 9]);
    b.extend([0u8; 8]);
    assert_eq!(all(&b).unwrap(), vec![vec![1, 2, 3, 4, 5, 6, 7, 8, 9]]);
}

#[test]
fn frame_parameters_are_allowed() {
    let mut b = b"YUV4MPEG2 W2 H1 F25:1 Cmono\n".to_vec();
    b.extend(b"FRAME Ip XYSCSS=MONO\n");
    b.extend([7, 8]);
    assert_eq!(all(&b).unwrap(), vec![vec![7, 8]]);
}

#[test]
fn a_limited_range_stream_is_stretched_to_full_range() {
    let mut b = b"YUV4MPEG2 W4 H1 F25:1 Cmono XCOLORRANGE=LIMITED\nFRAME\n".to_vec();
    b.extend([0, 16, 126, 235]);
    assert_eq!(all(&b).unwrap(), vec![vec![0, 0, 128, 255]]);
    let mut b = b"YUV4MPEG2 W4 H1 F25:1 Cmono XCOLORRANGE=FULL\nFRAME\n".to_vec();
    b.extend([0, 16, 126, 235]);
    assert_eq!(all(&b).unwrap(), vec![vec![0, 16, 126, 235]]);
}

#[test]
fn a_stream_that_ends_mid_frame_is_an_error_after_the_whole_frames() {
    let mut b = b"YUV4MPEG2 W4 H2 F25:1 Cmono\nFRAME\n".to_vec();
    b.extend([1; 8]);
    b.extend(b"FRAME\n");
    b.extend([2; 5]);
    let mut s = source(&b);
    assert_eq!(s.next_frame().unwrap().unwrap().grey.into_raw(), vec![1; 8]);
    let e = format!("{:#}", s.next_frame().unwrap_err());
    assert!(e.contains("ended in the middle of frame 1") && e.contains("11 of 14 bytes"), "{e}");
    assert!(s.next_frame().unwrap().is_none(), "nothing after the error");
    // Cut inside the FRAME line itself.
    let mut b = b"YUV4MPEG2 W4 H2 F25:1 Cmono\nFRAME\n".to_vec();
    b.extend([1; 8]);
    b.extend(b"FRA");
    assert!(err(&b).contains("middle of frame 1"), "{}", err(&b));
    // Cut inside the header.
    assert!(err(b"YUV4MPEG2 W4 H2").contains("inside its header"));
}

#[test]
fn unsupported_colour_spaces_are_refused_by_name() {
    let e = err(b"YUV4MPEG2 W4 H2 F25:1 C411\nFRAME\n");
    assert!(e.contains("C411 is not supported") && e.contains("mono"), "{e}");
    let e = err(b"YUV4MPEG2 W4 H2 F25:1 C420p10\nFRAME\n");
    assert!(e.contains("10-bit") && e.contains("8-bit"), "{e}");
    let e = err(b"YUV4MPEG2 W4 H2 F25:1 Cmono12\nFRAME\n");
    assert!(e.contains("12-bit"), "{e}");
}

#[test]
fn not_a_stream_empty_and_huge_frames_are_clear_errors() {
    assert!(err(b"").contains("empty"), "{}", err(b""));
    let png = b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR\n";
    assert!(err(png).contains("not a Y4M stream"), "{}", err(png));
    let e = err(b"YUV4MPEG2 W100000 H100000 F25:1 Cmono\n");
    assert!(e.contains("W100000 H100000") && e.contains("MiB"), "{e}");
    let e = err(b"YUV4MPEG2 F25:1 Cmono\nFRAME\n");
    assert!(e.contains("bad Y4M header"), "{e}");
    // Bytes between frames that are not a FRAME line.
    let mut b = b"YUV4MPEG2 W2 H1 F25:1 Cmono\nFRAME\n".to_vec();
    b.extend([1, 2]);
    b.extend(b"GARBAGE\n");
    assert!(err(&b).contains("frame 1 does not start with a FRAME line"), "{}", err(&b));
}

/// A reader that hands out what it is sent and blocks until then, like a pipe.
struct Pipe(std::sync::mpsc::Receiver<Vec<u8>>, Vec<u8>);

impl Read for Pipe {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if self.1.is_empty() {
            match self.0.recv() {
                Ok(b) => self.1 = b,
                Err(_) => return Ok(0),
            }
        }
        let n = buf.len().min(self.1.len());
        buf[..n].copy_from_slice(&self.1[..n]);
        self.1.drain(..n);
        Ok(n)
    }
}

#[test]
fn a_stream_that_stops_delivering_times_out() {
    let (tx, rx) = std::sync::mpsc::channel();
    let mut s = Y4mSource::spawn(Pipe(rx, Vec::new()), "camera", Duration::from_millis(200));
    let mut b = b"YUV4MPEG2 W2 H1 F25:1 Cmono\nFRAME\n".to_vec();
    b.extend([5, 6]);
    tx.send(b).unwrap();
    assert_eq!(s.next_frame().unwrap().unwrap().grey.into_raw(), vec![5, 6]);
    let t0 = std::time::Instant::now();
    let e = s.next_frame().unwrap_err().to_string();
    assert!(t0.elapsed() >= Duration::from_millis(200));
    assert!(e.contains("no frame for 0.2 s") && e.contains("after 1 frames"), "{e}");
    // It may come back: a slow camera is not a dead one.
    tx.send(b"FRAME\n\x07\x08".to_vec()).unwrap();
    assert_eq!(s.next_frame().unwrap().unwrap().grey.into_raw(), vec![7, 8]);
    drop(tx);
    assert!(s.next_frame().unwrap().is_none());
}
