//! A board on a serial port: the host side of the host link.
//!
//! Opens the port with `serialport`, paces writes to the line rate (a PTY or a USB bridge without
//! flow control would otherwise let a large upload overrun the board's receive buffers), uploads a
//! model blob (begin, chunks, commit; a lost chunk or an interrupted upload resumes where the
//! board says it stopped), and sends face crops with selective repeat.
use crate::data::crop;
use anyhow::{anyhow, bail, Context, Result};
use msr_shared::deliver::{FaceLink, LinkStats};
use msr_shared::host_port::HostPort;
use msr_shared::msg::{BoardToHost, HostToBoard, RoomCommand, Status, StoreReport};
use std::io::{Read, Write};
use std::time::{Duration, Instant};

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
    /// The id of the last face sent.
    frame_id: u16,
    /// Whether any message has come from the board in this session.
    heard: bool,
}

/// A session's first frame id: from the clock and the process id, so that two sessions seldom
/// start in the same stretch of ids.
fn first_id() -> u16 {
    let t = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64);
    let x = t ^ (std::process::id() as u64).rotate_left(32);
    (x ^ (x >> 16) ^ (x >> 32) ^ (x >> 48)) as u16
}

/// Whether `m` answers face `frame`: its detection, or an error that says why the board ran
/// nothing on it. A watchdog's error (`FaceTimeout`, `ServoTimeout` 0) or a servo fault is news
/// of the board, not an answer: one still queued from before the frame was taken for its
/// answer.
pub fn answers(m: &BoardToHost, frame: u16) -> bool {
    use msr_shared::msg::ErrorCode;
    match m {
        // While the arm is up every whole frame is answered with the reach's detection.
        BoardToHost::Detection(d) => d.frame == frame || (d.confirmed && d.reach.is_some()),
        BoardToHost::Error { code, detail } => match code {
            ErrorCode::BadFrame => *detail == frame as u32,
            ErrorCode::NoModel | ErrorCode::Version => true,
            // No servo positions for the decoder's input.
            ErrorCode::ServoTimeout => *detail == 1,
            _ => false,
        },
        _ => false,
    }
}

/// Whether `m` answers a step of a model upload: where the board stands, its acceptance, or its
/// refusal of the upload. Other errors (a watchdog's, say, queued since the last run) are news of
/// the board, not the upload's answer.
pub fn answers_upload(m: &BoardToHost) -> bool {
    use msr_shared::msg::ErrorCode;
    match m {
        BoardToHost::UploadAck { .. } | BoardToHost::ModelAccepted { .. } => true,
        BoardToHost::Error { code, .. } => matches!(code, ErrorCode::BadUpload | ErrorCode::BadModel | ErrorCode::Version),
        _ => false,
    }
}

/// Tries in a row in which nothing at all came back from the board before an upload is given
/// up: a lost begin or commit is tried again once, a board that went away is not waited for.
pub const SILENT_TRIES: usize = 2;

/// How long the PC waits for the board's ack of a face-frame round after its last byte went
/// out: USB serial bridges batch reads for up to 16 ms.
pub const ACK_TIMEOUT: Duration = Duration::from_millis(25);
/// Tries in a row (begin, chunks from where the board stands, commit) that get the board no
/// further before an upload is given up. A try that gets it further starts the count again, so
/// a long upload on a noisy line goes through gap by gap.
pub const UPLOAD_TRIES: usize = 8;

impl Session {
    /// Opens the serial port at `path` (8N1 at `baud` bits/s) and ends any frame a killed client
    /// left half-sent.
    pub fn open(path: &str, baud: u32) -> Result<Session> {
        if baud == 0 {
            bail!("baud rate must be positive");
        }
        let port = serialport::new(path, baud)
            .timeout(Duration::from_millis(5))
            .open()
            .with_context(|| format!("opening serial port {path}"))?;
        let mut faces = FaceLink::new(ACK_TIMEOUT.as_micros() as u64);
        // Not where the last session's ids were (see `FaceLink::skip_ids`); a start that lands
        // among them anyway is found by its missing answer ([`Session::send_face`]).
        faces.skip_ids(first_id());
        let mut s = Session {
            port,
            host: HostPort::default(),
            byte_time: Duration::from_secs_f64(10.0 / baud as f64),
            pending: Vec::new(),
            faces,
            t0: Instant::now(),
            upload_resent: 0,
            frame_id: 0,
            heard: false,
        };
        // A client killed mid-frame leaves the board's receiver holding part of a frame; a
        // delimiter ends it, so that this session's first message is read whole.
        s.send(&[0])?;
        Ok(s)
    }

    /// The id of the face [`Session::send_face`] sent last.
    pub fn frame_id(&self) -> u16 {
        self.frame_id
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

    /// Encodes one message in the host link's framing and sends it at the line rate.
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
        self.heard |= !out.is_empty();
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
    /// otherwise (the board then keeps the model it had). `timeout` is how long an answer is
    /// waited for: to the begin, and after the blob's last byte went out (plus the line time of
    /// what was sent, for a board that reads slower than the line). A try that gets no answer
    /// starts again with `ModelBegin`, which the board answers with where to resume. A board that
    /// says nothing at all (none there, or one that went away) is given up after
    /// [`SILENT_TRIES`] tries, or at once when it answers neither the begin nor a status request.
    pub fn upload(&mut self, blob: &[u8], timeout: Duration) -> Result<u32> {
        let crc32 = msr_shared::blob::CRC32.checksum(blob);
        let begin = HostToBoard::ModelBegin { len: blob.len() as u32, crc32 };
        let refused = |code, detail| anyhow!("the board refused the model: {code:?} (detail {detail})");
        let mut resume: Option<usize> = None;
        let mut sent_to = 0usize;
        // The furthest byte the board has said it holds, the tries since it moved, and the
        // tries in a row that got nothing at all back.
        let (mut best, mut stalled, mut silent) = (0usize, 0usize, 0usize);
        while stalled < UPLOAD_TRIES {
            stalled += 1;
            let from = match resume.take() {
                Some(n) => n,
                None => {
                    self.send_message(&begin)?;
                    let (msgs, _) = self.wait_for(timeout, answers_upload)?;
                    match msgs.iter().rev().find(|m| answers_upload(m)) {
                        Some(BoardToHost::UploadAck { next }) => *next as usize,
                        Some(BoardToHost::Error { code, detail }) => return Err(refused(*code, *detail)),
                        _ => {
                            silent = if msgs.is_empty() { silent + 1 } else { 0 };
                            if !self.heard {
                                // Nothing ever came back: a board that answers a status request
                                // lost the begin; none that does is not there.
                                if self.status(timeout).is_err() {
                                    bail!(
                                        "no answer from the board to the model upload's begin nor to a status request \
                                         within {timeout:?} each: no board on this port, or not at this baud"
                                    );
                                }
                            } else if silent >= SILENT_TRIES {
                                bail!(
                                    "the board stopped answering during the model upload: nothing came back in \
                                     {SILENT_TRIES} tries of {timeout:?}, at byte {best} of {}",
                                    blob.len()
                                );
                            }
                            continue;
                        }
                    }
                }
            };
            let from = from.min(blob.len());
            if from > best {
                (best, stalled) = (from, 0);
            }
            self.upload_resent += sent_to.saturating_sub(from) as u64;
            let bytes = self.host.encode_upload_from(blob, from);
            self.send(&bytes)?;
            sent_to = blob.len();
            let line = self.byte_time.mul_f64(bytes.len() as f64 * 1.1);
            let (msgs, _) = self.wait_for(timeout + line, answers_upload)?;
            silent = if msgs.is_empty() { silent + 1 } else { 0 };
            match msgs.iter().rev().find(|m| answers_upload(m)) {
                Some(BoardToHost::ModelAccepted { crc32 }) => return Ok(*crc32),
                Some(BoardToHost::Error { code, detail }) => return Err(refused(*code, *detail)),
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
                _ if silent >= SILENT_TRIES => bail!(
                    "the board stopped answering during the model upload: nothing came back in \
                     {SILENT_TRIES} tries, at byte {best} of {}",
                    blob.len()
                ),
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
        let at = msr_shared::msg::CropAt::subpixel([c.x as u16, c.y as u16], face.at);
        let id = self.faces.start(at, size, face.image(), now(self.t0));
        self.frame_id = id;
        let deadline = Instant::now() + timeout;
        let mut got = Vec::new();
        loop {
            // The whole batch is kept: what came after the answer in it is not dropped.
            let batch = self.step_faces()?;
            let answered = batch.iter().any(|m| answers(m, id));
            got.extend(batch);
            if answered {
                return Ok(got);
            }
            if Instant::now() >= deadline {
                // Unanswered: the board may hold ids near this one from an earlier session;
                // the next face starts past all it can take for old.
                self.faces.skip_ids(msr_shared::msg::STALE_WINDOW);
                return Ok(got);
            }
        }
    }

    /// One turn of the face link: the ack timeout, what is due on the line, what came back
    /// (acks taken by the link, the rest returned).
    fn step_faces(&mut self) -> Result<Vec<BoardToHost>> {
        let now = |t0: Instant| t0.elapsed().as_micros() as u64;
        self.faces.check(now(self.t0));
        let mut bytes = Vec::new();
        let host = &mut self.host;
        self.faces.pump(|m| bytes.extend(host.encode(m)));
        if !bytes.is_empty() {
            self.send(&bytes)?; // paced: the line is idle when it returns
        }
        self.faces.sent(now(self.t0));
        let mut got = self.poll()?;
        got.retain(|m| {
            self.faces.on_message(m);
            !is_ack(m)
        });
        Ok(got)
    }

    /// Ends a run of faces: the face in flight goes on until it gets through or fails (or
    /// `timeout` passes), then the board is asked for its status. Returns what the board sent
    /// before the status (a detection that came after its frame's period, say) and the status,
    /// so that nothing the board answered is lost.
    pub fn close(&mut self, timeout: Duration) -> Result<(Vec<BoardToHost>, Status)> {
        let deadline = Instant::now() + timeout;
        let mut got = Vec::new();
        while self.faces.in_flight_since().is_some() && Instant::now() < deadline {
            got.extend(self.step_faces()?);
        }
        let (before, st) = self.status_and_before(timeout)?;
        got.extend(before.into_iter().filter(|m| !is_ack(m)));
        Ok((got, st))
    }

    /// What the face link did so far, and the face bytes delivered per second of the session.
    pub fn link_stats(&self) -> (LinkStats, f64) {
        let s = self.faces.stats;
        (s, s.face_bytes as f64 / self.t0.elapsed().as_secs_f64().max(1e-9))
    }

    /// What the board's model store holds (its model's origin, the saved statistics).
    pub fn store(&mut self, timeout: Duration) -> Result<StoreReport> {
        self.send_message(&HostToBoard::GetStore)?;
        let (msgs, ok) = self.wait_for(timeout, |m| matches!(m, BoardToHost::Store(_)))?;
        match msgs.last() {
            Some(BoardToHost::Store(r)) if ok => Ok(*r),
            // Only a board that answers otherwise may run firmware without the store report.
            _ if self.status(timeout).is_ok() => {
                bail!("no answer to GetStore from the board within {timeout:?}, though it answers GetStatus (its firmware may predate GetStore)")
            }
            _ => bail!("no answer from the board within {timeout:?}: no board on this port, or not at this baud"),
        }
    }

    /// Sends a command to the board's online self-calibration and waits for its answer (a
    /// `Status`, or a `Store` report for a save); an `Error` the board sends first is returned
    /// as the failure.
    pub fn room(&mut self, cmd: RoomCommand, timeout: Duration) -> Result<()> {
        self.send_message(&HostToBoard::Room(cmd))?;
        let (msgs, ok) = self.wait_for(timeout, |m| {
            matches!(m, BoardToHost::Status(_) | BoardToHost::Store(_) | BoardToHost::Error { .. })
        })?;
        match msgs.last() {
            Some(BoardToHost::Error { code, detail }) => {
                bail!("the board refused {cmd:?}: {code:?} (detail {detail}); its store keeps nothing, or is busy")
            }
            Some(_) if ok => Ok(()),
            _ => bail!("no answer to Room({cmd:?}) from the board within {timeout:?} (its firmware may predate it)"),
        }
    }

    /// Asks for the board's status and waits up to `timeout` for it.
    pub fn status(&mut self, timeout: Duration) -> Result<Status> {
        self.status_and_before(timeout).map(|(_, st)| st)
    }

    /// Asks for the board's status; returns it and what the board sent before it.
    fn status_and_before(&mut self, timeout: Duration) -> Result<(Vec<BoardToHost>, Status)> {
        self.send_message(&HostToBoard::GetStatus)?;
        let (mut msgs, ok) = self.wait_for(timeout, |m| matches!(m, BoardToHost::Status(_)))?;
        match msgs.pop() {
            Some(BoardToHost::Status(s)) if ok => Ok((msgs, s)),
            _ => bail!("no status from the board within {timeout:?}"),
        }
    }

    /// The host side's own framing counters (CRC errors and resyncs on what the board sent).
    pub fn counters(&self) -> msr_shared::frame::LinkCounters {
        *self.host.counters()
    }
}

/// Protocol messages the face link and the upload consume; never shown to a caller.
fn is_ack(m: &BoardToHost) -> bool {
    matches!(m, BoardToHost::FrameAck(_) | BoardToHost::UploadAck { .. })
}
