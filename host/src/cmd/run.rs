//! `msr run`: stream frames to a board over a serial port and print what it reports.
//!
//! The host side of the host link as it runs against a real board: open the port with
//! `serialport`, optionally upload a model blob (begin, chunks, commit; the board answers
//! `ModelAccepted` or an error and keeps its previous model; a lost chunk or an interrupted
//! upload resumes where the board says it stopped), then for each frame crop the face with the
//! model's template, send it (selective repeat: what the board missed is sent again), and print
//! the board's answer (a detection, an error, a status) and at the end the link's goodput,
//! retransmissions and superseded frames. Writes are paced to the line rate: a PTY or a USB bridge without flow control would
//! otherwise let a large upload overrun the board's receive buffers.
use crate::camera::{self, SourceConfig, SourceOptions};
use crate::data::crop;
use msr_shared::host_port::HostPort;
use anyhow::{anyhow, bail, Context, Result};
use image::GrayImage;
use msr_shared::deliver::{FaceLink, LinkStats};
use msr_shared::msg::{BoardToHost, HostToBoard, Status, CHUNK};
use msr_sim::Robot;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Serial port of the board (e.g. /dev/ttyACM0, or a PTY the sim serves)
    #[arg(long)]
    pub port: String,
    /// Line rate, baud (1200..=20000000); a face crop must cross the line within a frame period
    #[arg(long, default_value_t = 921_600)]
    pub baud: u32,
    /// Model blob (.msrm): its face template crops the frames
    #[arg(long)]
    pub model: PathBuf,
    /// Upload the model to the board before streaming
    #[arg(long)]
    pub upload: bool,
    /// Camera frames: a folder of PNGs in name order, or `-`: a Y4M stream on standard input
    #[arg(long, conflicts_with_all = ["sim", "camera"], value_name = "DIR|-")]
    pub frames: Option<PathBuf>,
    /// A V4L2 camera, e.g. /dev/video0 (with the `v4l` feature)
    #[arg(long, conflicts_with = "sim", value_name = "DEV")]
    pub camera: Option<PathBuf>,
    /// Render frames from the sim instead, of this robot (red or skin): at home, a random mark
    /// from the 4th frame on
    #[arg(long, value_name = "ROBOT")]
    pub sim: Option<Robot>,
    /// Frames to render with --sim
    #[arg(long, default_value_t = 10)]
    pub count: usize,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Frames per second (0.1..=1000)
    #[arg(long, default_value_t = 10.0)]
    pub fps: f64,
    /// How long to wait for an upload's or a status request's answer, milliseconds (a frame's
    /// answer is waited for one frame period at most)
    #[arg(long, default_value_t = 2000)]
    pub timeout_ms: u64,
    /// Longest wait for a frame of a stream or camera, milliseconds
    #[arg(long, default_value_t = 5000, value_name = "MS")]
    pub frame_timeout_ms: u64,
    /// One JSON object per line
    #[arg(long)]
    pub json: bool,
}

/// Longest a write may make no progress.
pub const STALL: Duration = Duration::from_secs(2);

/// A board on a serial port.
pub struct Session {
    port: Box<dyn serialport::SerialPort>,
    host: HostPort,
    byte_time: Duration,
    pending: Vec<BoardToHost>,
    faces: FaceLink,
    /// The session's clock for the face link's timeouts.
    t0: Instant,
    /// Model bytes sent again on resuming uploads.
    pub upload_resent: u64,
}

/// How long the PC waits for the board's ack of a face-frame round after its last byte went
/// out: USB serial bridges batch reads for up to 16 ms.
pub const ACK_TIMEOUT: Duration = Duration::from_millis(25);
/// Tries in a row (begin, chunks from where the board stands, commit) that get the board no
/// further before an upload is given up. A try that gets it further starts the count again, so
/// a long upload on a noisy line goes through gap by gap.
pub const UPLOAD_TRIES: usize = 8;

impl Session {
    pub fn open(path: &str, baud: u32) -> Result<Session> {
        if baud == 0 {
            bail!("baud rate must be positive");
        }
        let port = serialport::new(path, baud)
            .timeout(Duration::from_millis(5))
            .open()
            .with_context(|| format!("opening serial port {path}"))?;
        Ok(Session {
            port,
            host: HostPort::default(),
            byte_time: Duration::from_secs_f64(10.0 / baud as f64),
            pending: Vec::new(),
            faces: FaceLink::new(ACK_TIMEOUT.as_micros() as u64),
            t0: Instant::now(),
            upload_resent: 0,
        })
    }

    /// Sends bytes at no more than the line rate. A full output buffer (the board, or the PTY
    /// peer, reading slowly) is waited out for up to [`STALL`].
    pub fn send(&mut self, bytes: &[u8]) -> Result<()> {
        for chunk in bytes.chunks(256) {
            let t0 = Instant::now();
            let mut rest = chunk;
            let mut last_progress = Instant::now();
            while !rest.is_empty() {
                match self.port.write(rest) {
                    Ok(n) if n > 0 => {
                        rest = &rest[n..];
                        last_progress = Instant::now();
                    }
                    Ok(_) => {}
                    Err(e)
                        if matches!(
                            e.kind(),
                            std::io::ErrorKind::TimedOut
                                | std::io::ErrorKind::WouldBlock
                                | std::io::ErrorKind::Interrupted
                        ) => {}
                    Err(e) => return Err(e).context("writing to the board"),
                }
                if last_progress.elapsed() > STALL {
                    bail!("the board has taken no bytes for {STALL:?}");
                }
            }
            let due = self.byte_time * chunk.len() as u32;
            if let Some(rest) = due.checked_sub(t0.elapsed()) {
                std::thread::sleep(rest);
            }
        }
        let _ = self.port.flush();
        Ok(())
    }

    pub fn send_message(&mut self, msg: &HostToBoard) -> Result<()> {
        let bytes = self.host.encode(msg);
        self.send(&bytes)
    }

    /// Reads what has arrived (waiting at most the port's short timeout).
    pub fn poll(&mut self) -> Result<Vec<BoardToHost>> {
        let mut buf = [0u8; 1024];
        let n = match self.port.read(&mut buf) {
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => 0,
            Err(e) => return Err(e).context("reading from the board"),
        };
        let mut out = std::mem::take(&mut self.pending);
        out.extend(self.host.receive(&buf[..n]));
        self.host.check_version()?;
        Ok(out)
    }

    /// Collects messages until one satisfies `done` (returned last) or `timeout` passes.
    pub fn wait_for(
        &mut self,
        timeout: Duration,
        mut done: impl FnMut(&BoardToHost) -> bool,
    ) -> Result<(Vec<BoardToHost>, bool)> {
        let t0 = Instant::now();
        let mut got = Vec::new();
        while t0.elapsed() < timeout {
            let msgs = self.poll()?;
            for (i, m) in msgs.iter().enumerate() {
                if done(m) {
                    got.extend_from_slice(&msgs[..=i]);
                    self.pending = msgs[i + 1..].to_vec();
                    return Ok((got, true));
                }
            }
            got.extend(msgs);
        }
        Ok((got, false))
    }

    /// Uploads a blob; `Ok(crc)` when the board accepted it, an error with the board's reason
    /// otherwise (the board then keeps the model it had). `timeout` is per try: a try that gets
    /// no answer starts again with `ModelBegin`, which the board answers with where to resume.
    pub fn upload(&mut self, blob: &[u8], timeout: Duration) -> Result<u32> {
        let crc32 = msr_shared::blob::CRC32.checksum(blob);
        let begin = HostToBoard::ModelBegin { len: blob.len() as u32, crc32 };
        let mut resume: Option<usize> = None;
        let mut sent_to = 0usize;
        // The furthest byte the board has said it holds, and the tries since it moved.
        let (mut best, mut stalled) = (0usize, 0usize);
        while stalled < UPLOAD_TRIES {
            stalled += 1;
            let from = match resume.take() {
                Some(n) => n,
                None => {
                    self.send_message(&begin)?;
                    let (msgs, _) = self.wait_for(timeout, |m| {
                        matches!(m, BoardToHost::UploadAck { .. } | BoardToHost::Error { .. })
                    })?;
                    match msgs.last() {
                        Some(BoardToHost::UploadAck { next }) => *next as usize,
                        Some(BoardToHost::Error { code, detail }) => {
                            bail!("the board refused the model: {code:?} (detail {detail})")
                        }
                        _ => continue,
                    }
                }
            };
            let from = from.min(blob.len());
            if from > best {
                (best, stalled) = (from, 0);
            }
            self.upload_resent += sent_to.saturating_sub(from) as u64;
            let mut bytes = Vec::new();
            for (i, data) in blob[from..].chunks(CHUNK).enumerate() {
                let offset = (from + i * CHUNK) as u32;
                bytes.extend(self.host.encode(&HostToBoard::ModelChunk { offset, data }));
            }
            bytes.extend(self.host.encode(&HostToBoard::ModelCommit));
            self.send(&bytes)?;
            sent_to = blob.len();
            let (msgs, _) = self.wait_for(timeout, |m| {
                matches!(
                    m,
                    BoardToHost::ModelAccepted { .. }
                        | BoardToHost::Error { .. }
                        | BoardToHost::UploadAck { .. }
                )
            })?;
            match msgs.last() {
                Some(BoardToHost::ModelAccepted { crc32 }) => return Ok(*crc32),
                Some(BoardToHost::Error { code, detail }) => {
                    bail!("the board refused the model: {code:?} (detail {detail})")
                }
                // A gap: go back to where the board stands (its answer to the commit, if a gap
                // answer came first, says the same or later).
                Some(BoardToHost::UploadAck { next }) => {
                    let later = self.wait_for(Duration::from_millis(20), |m| {
                        matches!(m, BoardToHost::UploadAck { .. } | BoardToHost::ModelAccepted { .. })
                    })?;
                    match later.0.last() {
                        Some(BoardToHost::ModelAccepted { crc32 }) => return Ok(*crc32),
                        Some(BoardToHost::UploadAck { next }) => resume = Some(*next as usize),
                        _ => resume = Some(*next as usize),
                    }
                }
                _ => {}
            }
        }
        bail!(
            "the model upload got no further than byte {best} of {} in {UPLOAD_TRIES} tries in a row of {timeout:?}",
            blob.len()
        )
    }

    /// Sends one face crop and waits up to `timeout` for the board's answer to it (a detection
    /// or an error), sending again what the board says it missed. While the arm is up the board
    /// answers frames with the reach in progress. A frame not through by `timeout` is
    /// superseded by the next one. Protocol messages (acks) are not returned.
    pub fn send_face(&mut self, face: &crop::Face, timeout: Duration) -> Result<Vec<BoardToHost>> {
        let now = |t0: Instant| t0.elapsed().as_micros() as u64;
        let c = face.crop;
        let size = [c.width as u16, c.height as u16];
        let at = msr_shared::msg::CropAt::subpixel([c.x as u16, c.y as u16], face.shift);
        self.faces.start(at, size, face.grey.clone(), now(self.t0));
        let deadline = Instant::now() + timeout;
        let mut got = Vec::new();
        loop {
            self.faces.check(now(self.t0));
            let mut bytes = Vec::new();
            let host = &mut self.host;
            self.faces.pump(|m| bytes.extend(host.encode(m)));
            if !bytes.is_empty() {
                self.send(&bytes)?; // paced: the line is idle when it returns
            }
            self.faces.sent(now(self.t0));
            for m in self.poll()? {
                self.faces.on_message(&m);
                match m {
                    BoardToHost::FrameAck(_) | BoardToHost::UploadAck { .. } => {}
                    BoardToHost::Detection(_) | BoardToHost::Error { .. } => {
                        got.push(m);
                        return Ok(got);
                    }
                    m => got.push(m),
                }
            }
            if Instant::now() >= deadline {
                return Ok(got);
            }
        }
    }

    /// What the face link did so far, and the face bytes delivered per second of the session.
    pub fn link_stats(&self) -> (LinkStats, f64) {
        let s = self.faces.stats;
        (s, s.face_bytes as f64 / self.t0.elapsed().as_secs_f64().max(1e-9))
    }

    pub fn status(&mut self, timeout: Duration) -> Result<Status> {
        self.send_message(&HostToBoard::GetStatus)?;
        let (msgs, ok) = self.wait_for(timeout, |m| matches!(m, BoardToHost::Status(_)))?;
        match msgs.last() {
            Some(BoardToHost::Status(s)) if ok => Ok(*s),
            _ => bail!("no status from the board within {timeout:?}"),
        }
    }

    /// The host side's own framing counters (CRC errors and resyncs on what the board sent).
    pub fn counters(&self) -> msr_shared::frame::LinkCounters {
        *self.host.counters()
    }
}

/// The frames of a folder, in name order.
pub fn folder_frames(dir: &Path) -> Result<Vec<(String, GrayImage)>> {
    collect(&SourceConfig::Folder(dir.to_path_buf()))
}

/// Frames rendered by the sim at home: the first three without a mark, then one random mark.
pub fn sim_frames(robot: Robot, count: usize, seed: u64) -> Vec<(String, GrayImage)> {
    collect(&sim_source(robot, count, seed)).expect("the sim source does not fail")
}

/// `msr run --sim`'s source: at home, a random mark from the 4th frame on.
pub fn sim_source(robot: Robot, count: usize, seed: u64) -> SourceConfig {
    SourceConfig::Sim { robot, count: Some(count), seed, mark_from: Some(3) }
}

fn collect(cfg: &SourceConfig) -> Result<Vec<(String, GrayImage)>> {
    let mut src = camera::open(cfg, &SourceOptions::default())?;
    let mut out = Vec::new();
    while let Some(f) = src.next_frame()? {
        out.push((f.name, f.grey));
    }
    Ok(out)
}

/// One readable line for a board message.
pub fn describe(m: &BoardToHost) -> String {
    match m {
        BoardToHost::Detection(d) => {
            let blob = d.blob.map_or("no mark".to_string(), |b| {
                format!("mark at ({:.1}, {:.1}), {} px, box {:?}", b.centroid[0], b.centroid[1], b.area, b.box_xyxy)
            });
            let reach = match (d.confirmed, d.reach) {
                (true, Some(r)) => format!("; REACH {:?}", r.map(|v| (v * 1000.0).round() / 1000.0)),
                _ => String::new(),
            };
            format!("frame {}: head ({:.3}, {:.3}) rad, {blob}{reach}", d.frame, d.head[0], d.head[1])
        }
        BoardToHost::Error { code, detail } => format!("error {code:?} (detail {detail})"),
        BoardToHost::Status(s) => format!(
            "status: {:?}, model crc {:08x}, {} frames, {} detections, {} reaches, host link {} CRC errors / {} resyncs, \
             servo bus {} CRC errors / {} resyncs, watchdog trips face {} servo {}, clamped targets {}",
            s.mode,
            s.model_crc,
            s.frames,
            s.detections,
            s.reaches,
            s.host_link.crc_errors,
            s.host_link.resyncs(),
            s.servo_link.crc_errors,
            s.servo_link.resyncs(),
            s.face_watchdog_trips,
            s.servo_watchdog_trips,
            s.clamped_targets
        ),
        BoardToHost::ModelAccepted { crc32 } => format!("model accepted, crc {crc32:08x}"),
        BoardToHost::Pong { nonce } => format!("pong {nonce}"),
        BoardToHost::ServoBus(r) => format!("servo bus: {r:?}"),
        BoardToHost::HeadAt { head } => format!(
            "head settled at yaw {:.3} deg, pitch {:.3} deg",
            head[0].to_degrees(),
            head[1].to_degrees()
        ),
        BoardToHost::FrameAck(a) => format!("frame {} round {}: {:?}", a.frame, a.round, a.state),
        BoardToHost::UploadAck { next } => format!("upload: the board wants byte {next} next"),
        BoardToHost::SelfGate(g) => format!(
            "self gate at frame {}: {:?}, gain ratio {:.3}, rest {:.2} px, frames {:?}, {} ms",
            g.frame, g.decision, g.gain_ratio, g.rest_px, g.frames, g.elapsed_ms
        ),
    }
}

fn print(m: &BoardToHost, json: bool) -> Result<()> {
    if json {
        println!("{}", serde_json::to_string(m)?);
    } else {
        println!("{}", describe(m));
    }
    Ok(())
}

pub fn run(a: Args) -> Result<()> {
    if !(a.fps.is_finite() && a.fps > 0.0) {
        bail!("--fps must be positive");
    }
    let blob = crate::episode::read_model(&a.model)?;
    let model = msr_shared::blob::Model::parse(&blob).map_err(|e| anyhow!("model: {e}"))?;
    let cropper = crate::detect::cropper_of(&model)?;
    let timeout = Duration::from_millis(a.timeout_ms);
    let period = Duration::from_secs_f64(1.0 / a.fps);
    // A frame that cannot cross the line within its period would pile up unanswered for ever.
    let face_wire = HostPort::default()
        .encode_face(
            [0, 0],
            [model.face_w as u32, model.face_h as u32],
            &vec![0u8; model.face_w as usize * model.face_h as usize],
        )
        .map_err(|e| anyhow!("model face size: {e}"))?;
    let frame_s = face_wire.len() as f64 * 10.0 / a.baud as f64;
    if frame_s > period.as_secs_f64() {
        bail!(
            "at --baud {} a face crop ({} bytes on the wire) takes {frame_s:.2} s, longer than the \
             frame period {:.2} s of --fps {}: raise --baud or lower --fps",
            a.baud,
            face_wire.len(),
            period.as_secs_f64(),
            a.fps
        );
    }
    let source = match (&a.frames, &a.camera, a.sim) {
        (Some(p), _, _) => SourceConfig::frames_arg(p),
        (None, Some(dev), _) => SourceConfig::Camera(dev.clone()),
        (None, None, Some(robot)) => sim_source(robot, a.count, a.seed),
        (None, None, None) => bail!("give --frames DIR|-, --camera DEV or --sim red|skin"),
    };
    let opts = SourceOptions {
        timeout: Duration::from_millis(a.frame_timeout_ms),
        fps: a.fps,
        ..SourceOptions::default()
    };
    let mut frames = camera::open(&source, &opts)?;
    let mut s = Session::open(&a.port, a.baud)?;
    if a.upload {
        // An upload takes about 11 bits a byte on the line; allow for it.
        let line = Duration::from_secs_f64(blob.len() as f64 * 11.0 / a.baud as f64);
        if !a.json {
            eprintln!(
                "uploading {} bytes, about {:.1} s at {} baud",
                blob.len(),
                line.as_secs_f64(),
                a.baud
            );
        }
        let crc = s.upload(&blob, timeout + line)?;
        print(&BoardToHost::ModelAccepted { crc32: crc }, a.json)?;
    }
    while let Some(camera::Frame { name, grey: frame }) = frames.next_frame()? {
        let t0 = Instant::now();
        let face = cropper.crop(&frame).with_context(|| format!("frame {name}"))?;
        let msgs = s.send_face(&face, period.min(timeout))?;
        if !a.json {
            println!("{name}: face at ({}, {})", face.crop.x, face.crop.y);
        }
        for m in &msgs {
            print(m, a.json)?;
        }
        if let Some(rest) = period.checked_sub(t0.elapsed()) {
            std::thread::sleep(rest);
        }
    }
    let st = s.status(timeout)?;
    print(&BoardToHost::Status(st), a.json)?;
    let (link, goodput) = s.link_stats();
    if a.json {
        let j = serde_json::json!({ "link": link, "goodput_bytes_per_s": goodput, "upload_resent_bytes": s.upload_resent });
        println!("{j}");
    } else {
        println!(
            "link: {} of {} frames through, {} superseded, goodput {:.0} face bytes/s, {} chunks sent again, \
             {} polls ({} after a timeout), {} model bytes sent again",
            link.delivered, link.frames, link.superseded, goodput, link.chunks_resent, link.polls, link.timeouts, s.upload_resent
        );
    }
    let _ = std::io::stdout().flush();
    Ok(())
}

/// Reads everything a reader has now (for tests).
pub fn drain(r: &mut dyn Read) -> Vec<u8> {
    let mut out = Vec::new();
    let mut buf = [0u8; 1024];
    while let Ok(n) = r.read(&mut buf) {
        if n == 0 {
            break;
        }
        out.extend_from_slice(&buf[..n]);
    }
    out
}
