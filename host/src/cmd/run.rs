//! `msr run`: stream frames to a board over a serial port and print what it reports.
//!
//! The shell around [`crate::session::Session`]: optionally upload a model blob (the board answers
//! `ModelAccepted` or an error and keeps its previous model), then for each frame crop the face
//! with the model's template, send it, and print the board's answer (a detection, an error, a
//! status) and at the end the link's goodput, retransmissions and superseded frames.
use crate::camera::{self, SourceConfig, SourceOptions};
use crate::session::Session;
use msr_shared::host_port::HostPort;
use anyhow::{anyhow, bail, Context, Result};
use image::GrayImage;
use msr_shared::msg::{BoardToHost, Mode};
use msr_sim::Robot;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// `msr run`'s flags: the board's line, the model, the frames' source, the pace and the outputs.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The board's line; at `--baud` a face crop must cross it within a frame period
    #[command(flatten)]
    pub line: super::BoardLine,
    /// Model blob (.msrm): its face template crops the frames
    #[arg(long)]
    pub model: PathBuf,
    /// Upload the model to the board before streaming
    #[arg(long)]
    pub upload: bool,
    /// Camera frames: a folder of PNGs in name order, or `-`: a Y4M stream on standard input
    #[arg(long, conflicts_with_all = ["sim", "camera"], value_name = "DIR|-")]
    pub frames: Option<PathBuf>,
    /// A V4L2 camera, e.g. /dev/video0 (Linux), held still once its picture settled
    /// (--camera-hold)
    #[arg(long, conflicts_with = "sim", value_name = "DEV")]
    pub camera: Option<PathBuf>,
    /// How a V4L2 camera is held.
    #[command(flatten)]
    pub hold: super::camera_hold::HoldArgs,
    /// Render frames from the sim instead, of this robot (red or skin): at home, a random mark
    /// from the 4th frame on
    #[arg(long, value_name = "ROBOT")]
    pub sim: Option<Robot>,
    /// Frames to render with --sim
    #[arg(long, default_value_t = 10)]
    pub count: usize,
    /// How the light changes over the --sim frames (10 a second of sim time)
    #[arg(long, value_enum, default_value_t = super::light::RunLight::Fixed, requires = "sim")]
    pub light: super::light::RunLight,
    /// The --sim camera's imperfections
    #[command(flatten)]
    pub imperfect: super::imperfect::CameraFlags,
    /// Seed of the --sim frames (the mark, the light, the camera noise)
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
    /// Also write the session as an MCAP file (ROS 2 messages: frames, face crops, saliency,
    /// annotations, reported head, reach targets, board status) for Foxglove or `ros2 bag play`
    #[arg(long, value_name = "FILE")]
    pub mcap: Option<PathBuf>,
    /// Serving the session live to Foxglove.
    #[command(flatten)]
    pub live: super::live::LiveFlags,
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
    SourceConfig::Sim { robot, count: Some(count), seed, mark_from: Some(3), light: Default::default(), camera: Default::default() }
}

fn collect(cfg: &SourceConfig) -> Result<Vec<(String, GrayImage)>> {
    let mut src = camera::open(cfg, &SourceOptions::default())?;
    let mut out = Vec::new();
    while let Some(f) = src.next_frame()? {
        out.push((f.name, f.grey));
    }
    Ok(out)
}

pub use crate::describe::describe;

fn print(m: &BoardToHost, json: bool) -> Result<()> {
    if json {
        println!("{}", serde_json::to_string(m)?);
    } else {
        println!("{}", describe(m));
    }
    Ok(())
}

/// Refuses a board that runs another model than `want` (from `path`).
pub fn check_model(runs: u32, want: u32, path: &Path) -> Result<()> {
    if runs == want {
        return Ok(());
    }
    if runs == 0 {
        bail!("the board has no model; give --upload to upload {}", path.display());
    }
    bail!(
        "the board runs model {runs:08x}, not {want:08x} of {}: give --upload to upload it, or the model the board runs",
        path.display()
    )
}

/// Streams the frames to the board (after an upload, with `--upload`) and prints each answer
/// and the link's figures at the end.
pub fn run(a: Args) -> Result<()> {
    if !(a.fps.is_finite() && a.fps > 0.0) {
        bail!("--fps must be positive");
    }
    let blob = crate::fsio::read_blob(&a.model)?;
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
    let frame_s = face_wire.len() as f64 * 10.0 / a.line.baud as f64;
    if frame_s > period.as_secs_f64() {
        bail!(
            "at --baud {} a face crop ({} bytes on the wire) takes {frame_s:.2} s, longer than the \
             frame period {:.2} s of --fps {}: raise --baud or lower --fps",
            a.line.baud,
            face_wire.len(),
            period.as_secs_f64(),
            a.fps
        );
    }
    if a.camera.is_none() {
        a.hold.check_unused()?;
    }
    let source = match (&a.frames, &a.camera, a.sim) {
        (Some(p), _, _) => SourceConfig::frames_arg(p),
        (None, Some(dev), _) => SourceConfig::Camera { dev: dev.clone(), hold: a.hold.hold()? },
        (None, None, Some(robot)) => match sim_source(robot, a.count, a.seed) {
            SourceConfig::Sim { robot, count, seed, mark_from, .. } => {
                SourceConfig::Sim { robot, count, seed, mark_from, light: a.light.into(), camera: a.imperfect.imperfections(seed) }
            }
            other => other,
        },
        (None, None, None) => return Err(super::usage("give --frames DIR|-, --camera DEV or --sim red|skin")),
    };
    let opts = SourceOptions {
        timeout: Duration::from_millis(a.frame_timeout_ms),
        fps: a.fps,
        ..SourceOptions::default()
    };
    let mut frames = camera::open(&source, &opts)?;
    let mut s = Session::open(&a.line.port, a.line.baud)?;
    // A halted board is said so before its answers (or their absence) are read.
    if !a.upload {
        if let Ok(st) = s.status(timeout) {
            if st.mode == Mode::Halted && !a.json {
                eprintln!("{}", halted(&st, true));
            }
        }
    }
    if a.upload {
        // An upload takes about 11 bits a byte on the line; allow for it.
        let line = Duration::from_secs_f64(blob.len() as f64 * 11.0 / a.line.baud as f64);
        if !a.json {
            eprintln!(
                "uploading {} bytes, about {:.1} s at {} baud",
                blob.len(),
                line.as_secs_f64(),
                a.line.baud
            );
        }
        let crc = s.upload(&blob, timeout)?;
        print(&BoardToHost::ModelAccepted { crc32: crc }, a.json)?;
    } else {
        // Frames cropped with one model's template and read with another's: refuse.
        let runs = s.status(timeout)?.model_crc;
        check_model(runs, model.crc32, &a.model)?;
    }
    let live = a.live.start(a.json)?;
    let mut log = (a.mcap.is_some() || live.is_some()).then(|| {
        let l = crate::rosbag::session::SessionLog::with_saliency(&blob);
        match &live {
            Some(v) => l.live(v.clone(), a.mcap.is_none()),
            None => l,
        }
    });
    let start = Instant::now();
    let us = || start.elapsed().as_micros() as u64;
    let mut head = [0f32; 2];
    // Faces sent and not (yet) answered, by id: a late answer still counts; the rest are said.
    let mut unanswered: Vec<(u16, String)> = Vec::new();
    let mut sent = 0usize;
    let mut stream = || -> Result<()> {
        while let Some(camera::Frame { name, grey: frame }) = frames.next_frame()? {
            let t0 = Instant::now();
            let face = cropper.crop(&frame).with_context(|| format!("frame {name}"))?;
            let msgs = s.send_face(&face, period.min(timeout))?;
            // The id the session gave this face: the one the board's answers carry.
            let id = s.frame_id();
            sent += 1;
            if let Some(l) = &mut log {
                // The saliency at the head angles the board last reported.
                l.frame(us(), id, &frame, &face, None, head);
            }
            for m in &msgs {
                if let BoardToHost::Detection(d) = m {
                    head = d.head;
                }
                if let Some(l) = &mut log {
                    l.board(us(), m);
                }
            }
            if !a.json {
                println!("{name}: face at ({}, {}), frame {id}", face.crop.x, face.crop.y);
            }
            unanswered.retain(|(f, _)| !msgs.iter().any(|m| matches!(m, BoardToHost::Detection(d) if d.frame == *f)));
            if !msgs.iter().any(|m| crate::session::answers(m, id)) {
                unanswered.push((id, name.clone()));
            }
            for m in &msgs {
                print(m, a.json)?;
            }
            if let Some(rest) = period.checked_sub(t0.elapsed()) {
                std::thread::sleep(rest);
            }
        }
        Ok(())
    };
    let streamed = stream();
    // The answers to faces already sent still count when the source failed (a cut stream):
    // they are printed before its error.
    let closed = s.close(timeout);
    if let Ok((late, st)) = &closed {
        for m in late {
            unanswered.retain(|(f, _)| !matches!(m, BoardToHost::Detection(d) if d.frame == *f));
            print(m, a.json)?;
            if let Some(l) = &mut log {
                l.board(us(), m);
            }
        }
        if let Some(l) = &mut log {
            l.status(us(), st);
        }
    }
    // What was streamed is written even when the source failed.
    if let Some(stats) = a.live.finish(live) {
        if a.json {
            println!("{}", serde_json::json!({ "live": stats }));
        } else {
            eprintln!("{stats}");
        }
    }
    if let (Some(p), Some(mut l)) = (&a.mcap, log) {
        l.close()?;
        let counts = crate::rosbag::session::write_logs(p, [&l])?;
        if !a.json {
            eprintln!("wrote {}: {}", p.display(), serde_json::to_string(&counts)?);
        }
    }
    // A face the board never answered is said so (also before an error): never "no mark",
    // never "through".
    for (id, name) in &unanswered {
        if a.json {
            println!("{}", serde_json::json!({ "unanswered": { "frame": id, "name": name } }));
        } else {
            println!("{name}: frame {id}: no answer from the board (dropped, or not run)");
        }
    }
    streamed?;
    let (_, st) = closed?;
    print(&BoardToHost::Status(st), a.json)?;
    let (link, goodput) = s.link_stats();
    let answered = sent - unanswered.len();
    if a.json {
        let j = serde_json::json!({ "link": link, "answered": answered, "sent": sent, "goodput_bytes_per_s": goodput, "upload_resent_bytes": s.upload_resent });
        println!("{j}");
    } else {
        println!(
            "link: {answered} of {sent} frames answered, {} delivered whole, {} superseded, goodput {:.0} face bytes/s, \
             {} chunks sent again, {} polls ({} after a timeout), {} model bytes sent again",
            link.delivered, link.superseded, goodput, link.chunks_resent, link.polls, link.timeouts, s.upload_resent
        );
    }
    let _ = std::io::stdout().flush();
    if st.mode == Mode::Halted {
        if stopped_by_face_watchdog(&st) {
            // The stream has ended: 500 ms after its last whole frame the board holds still, as
            // on a robot whose camera stopped, and the closing status can come later than that
            // (a slow or busy PC). A halt from the servos is an error; this one is the end.
            if !a.json {
                eprintln!("the board holds still since the stream ended (its face watchdog: no whole frame for 500 ms)");
            }
        } else {
            bail!("{}", halted(&st, false));
        }
    }
    if sent > 0 && answered == 0 {
        bail!("the board answered none of the {sent} frames (mode {:?}): see its status line above", st.mode);
    }
    Ok(())
}

/// Whether a halted board stopped for want of frames alone (its servos are well).
fn stopped_by_face_watchdog(st: &msr_shared::msg::Status) -> bool {
    st.face_watchdog_trips > 0 && st.servo_watchdog_trips == 0
}

/// What a halted board means and what brings it back.
fn halted(st: &msr_shared::msg::Status, before: bool) -> String {
    let why = if stopped_by_face_watchdog(st) {
        "its face watchdog tripped (no whole frame for 500 ms); whole frames bring it back"
    } else if st.servo_watchdog_trips > 0 {
        "its servo watchdog tripped (no servo state for 100 ms); servo states again bring it back"
    } else {
        "its servo bus faulted; check the servos and restart the board"
    };
    if before {
        format!("the board is halted: {why}")
    } else {
        format!("the board is halted at the end of the run: {why}")
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_another_model() {
        let p = std::path::Path::new("m.msrm");
        assert!(check_model(5, 5, p).is_ok());
        let e = check_model(4, 5, p).unwrap_err().to_string();
        assert!(e.contains("runs model 00000004, not 00000005 of m.msrm"), "{e}");
        assert!(check_model(0, 5, p).unwrap_err().to_string().contains("no model"));
    }
}
