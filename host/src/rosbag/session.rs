//! What a session (mirror-test trials, a run with a board, a recording) saw and did, as ROS 2
//! messages for an MCAP file and for the live view ([`crate::live`]). Topics:
//!
//! | topic | type | what |
//! |---|---|---|
//! | `/camera/image` | sensor_msgs/msg/Image (mono8) | each camera frame streamed, grey, as cropped |
//! | `/face/image` | sensor_msgs/msg/Image (mono8) | the face crop sent to the board |
//! | `/face/predicted` | sensor_msgs/msg/Image (mono8) | the face the firmware pipeline's decoder predicts at the head pose of that crop (sim) |
//! | `/face/saliency` | sensor_msgs/msg/Image (mono8) | the firmware pipeline's saliency on that crop, 128 = the threshold (sim) |
//! | `/camera/annotations` | foxglove_msgs/msg/ImageAnnotations | one per frame: the crop box (grey), the mark's truth (green, sim), the board's blob box and centroid (red) |
//! | `/joint_states` | sensor_msgs/msg/JointState | reported joint angles |
//! | `/joint_commands` | sensor_msgs/msg/JointState | commanded joint angles (servo goals, sim) |
//! | `/board/head` | sensor_msgs/msg/JointState | the head angles the board reported with each detection |
//! | `/reach/target` | sensor_msgs/msg/JointState | the reach targets the board streamed |
//! | `/board/status` | diagnostic_msgs/msg/DiagnosticArray | the board's status counters |
//! | `/msr/trial` | diagnostic_msgs/msg/DiagnosticArray | a trial's outcome, at its start (mirror-test) |
//!
//! Messages are kept per trial in memory (about 10 MB a trial of the sim) and written in time
//! order when the session ends.
use super::msgs;
use super::write::{self, McapLog};
use crate::data::crop::Face;
use anyhow::Result;
use image::GrayImage;
use msr_shared::msg::{BoardToHost, Detection};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::Path;

/// One message, encoded.
#[derive(Clone, Debug)]
pub struct Logged {
    /// When, in nanoseconds from the start of the trial or session.
    pub t_ns: u64,
    /// The topic it goes on (one of the table above).
    pub topic: &'static str,
    /// Its ROS 2 type name ([`msgs::IMAGE`], ...).
    pub type_name: &'static str,
    /// The message in CDR with ROS 2's encapsulation header, stamped from the start as `t_ns` is.
    pub cdr: Vec<u8>,
}

struct Pending {
    t_ns: u64,
    crop: [f64; 4],
    truth: Option<[u32; 4]>,
}

/// The messages of one trial or session, times in nanoseconds from its start.
#[derive(Default)]
pub struct SessionLog {
    /// The messages kept for the MCAP file, as they came (none when published live only).
    pub msgs: Vec<Logged>,
    pending: BTreeMap<u16, Pending>,
    /// Parsed model and the firmware's workspace, for the saliency image.
    saliency: Option<(Vec<u8>, Box<msr_firmware::Workspace>)>,
    error: Option<String>,
    /// Each message also goes out live (`--live`), its stamps moved by `base_ns`.
    live: Option<(std::sync::Arc<crate::live::Live>, u64)>,
    /// Published live only, not kept in `msgs` (no `--mcap`).
    live_only: bool,
}

impl std::fmt::Debug for SessionLog {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "SessionLog({} messages)", self.msgs.len())
    }
}

impl Clone for SessionLog {
    /// A copy of the messages only (what is written).
    fn clone(&self) -> SessionLog {
        SessionLog { msgs: self.msgs.clone(), ..Default::default() }
    }
}

const CAMERA: &str = "camera";

impl SessionLog {
    /// A log that also computes the saliency image with `blob`'s firmware pipeline.
    pub fn with_saliency(blob: &[u8]) -> SessionLog {
        SessionLog { saliency: Some((blob.to_vec(), Box::new(msr_firmware::Workspace::new()))), ..Default::default() }
    }

    /// The log of a mirror-test trial: for `--mcap` (kept) and `--live` (published as it comes).
    pub fn for_episode(mcap: Option<&LogModel>, live: Option<&LiveTap>) -> Option<SessionLog> {
        let model = mcap.or(live.map(|l| &l.model))?;
        let log = SessionLog::with_saliency(&model.0);
        Some(match live {
            Some(l) => log.live(l.live.clone(), mcap.is_none()),
            None => log,
        })
    }

    /// Also publishes every message on `live`, stamped from now; `only`: keeps none.
    pub fn live(mut self, live: std::sync::Arc<crate::live::Live>, only: bool) -> SessionLog {
        self.live = Some((live, crate::live::now_ns()));
        self.live_only = only;
        self
    }

    fn push<T: Serialize>(&mut self, t_ns: u64, topic: &'static str, type_name: &'static str, msg: &T) {
        match msgs::encode(msg) {
            Ok(cdr) => {
                let m = Logged { t_ns, topic, type_name, cdr };
                if let Some((live, base)) = &self.live {
                    // A client never stops the session: publishing fails only on a topic
                    // the server lacks, a bug reported like an encoding error.
                    if let Err(e) = shift(&m, *base).and_then(|b| live.publish(topic, &b)) {
                        self.error.get_or_insert(e.to_string());
                    }
                }
                if !self.live_only {
                    self.msgs.push(m);
                }
            }
            Err(e) => {
                self.error.get_or_insert(format!("{topic}: {e}"));
            }
        }
    }

    /// A camera frame and the face crop sent to the board as frame `id`; `truth` is the mark's
    /// box in the frame when known (sim); `head` the angles the pipeline would use.
    pub fn frame(&mut self, t_us: u64, id: u16, frame: &GrayImage, face: &Face, truth: Option<[u32; 4]>, head: [f32; 2]) {
        let t = t_us * 1000;
        let (w, h) = frame.dimensions();
        self.push(t, "/camera/image", msgs::IMAGE, &write::mono8(t, CAMERA, w, h, frame.as_raw().clone()));
        let c = face.crop;
        self.push(t, "/face/image", msgs::IMAGE, &write::mono8(t, "face", c.width, c.height, face.grey.clone()));
        let drawn = self.saliency.as_mut().and_then(|(blob, ws)| {
            let model = msr_shared::blob::Model::parse(blob).ok()?;
            let d = crate::detect::fixed::detect_with(ws, &model, face, head).ok()?;
            let predicted: Vec<u8> = d.predicted.iter().map(|p| (p * 255.0).round().clamp(0.0, 255.0) as u8).collect();
            // Saliency is in sigma units; the blob's threshold maps to 128.
            let thr = model.novelty.threshold.max(1e-6);
            let saliency = d.saliency.iter().map(|s| (s / thr * 128.0).clamp(0.0, 255.0) as u8).collect::<Vec<u8>>();
            Some((predicted, saliency))
        });
        if let Some((predicted, saliency)) = drawn {
            self.push(t, "/face/predicted", msgs::IMAGE, &write::mono8(t, "face", c.width, c.height, predicted));
            self.push(t, "/face/saliency", msgs::IMAGE, &write::mono8(t, "face", c.width, c.height, saliency));
        }
        let crop = [c.x as f64, c.y as f64, (c.x + c.width) as f64 - 1.0, (c.y + c.height) as f64 - 1.0];
        // A frame id comes round again after 65536 frames: the older one is answered by then.
        if let Some(old) = self.pending.insert(id, Pending { t_ns: t, crop, truth }) {
            self.annotate(old, None);
        }
    }

    fn annotate(&mut self, p: Pending, d: Option<&Detection>) {
        let t = p.t_ns;
        let mut a = msgs::ImageAnnotations::default();
        a.points.push(write::box_outline(t, p.crop, write::GREY));
        if let Some(b) = p.truth {
            a.points.push(write::box_outline(t, b.map(|v| v as f64), write::GREEN));
        }
        let label = match d {
            None => "no answer".to_string(),
            Some(d) => match &d.blob {
                None => "no mark".to_string(),
                Some(b) => {
                    a.points.push(write::box_outline(t, b.box_xyxy.map(|v| v as f64), write::RED));
                    a.circles.push(write::circle(t, b.centroid[0] as f64, b.centroid[1] as f64, 4.0, write::RED));
                    format!("blob {} px{}", b.area, if d.confirmed { ", REACH" } else { "" })
                }
            },
        };
        a.texts.push(write::text(t, p.crop[0], p.crop[1] - 2.0, &label, write::RED));
        self.push(t, "/camera/annotations", msgs::IMAGE_ANNOTATIONS, &a);
    }

    /// A frame not sent to a board (`msr record`): its images and an annotation with `label`.
    pub fn frame_labelled(&mut self, t_us: u64, frame: &GrayImage, face: &Face, label: &str) {
        let t = t_us * 1000;
        let (w, h) = frame.dimensions();
        self.push(t, "/camera/image", msgs::IMAGE, &write::mono8(t, CAMERA, w, h, frame.as_raw().clone()));
        let c = face.crop;
        self.push(t, "/face/image", msgs::IMAGE, &write::mono8(t, "face", c.width, c.height, face.grey.clone()));
        let crop = [c.x as f64, c.y as f64, (c.x + c.width) as f64 - 1.0, (c.y + c.height) as f64 - 1.0];
        let mut a = msgs::ImageAnnotations::default();
        a.points.push(write::box_outline(t, crop, write::GREY));
        a.texts.push(write::text(t, crop[0], crop[1] - 2.0, label, write::GREEN));
        self.push(t, "/camera/annotations", msgs::IMAGE_ANNOTATIONS, &a);
    }

    /// A message from the board at `t_us`: detections annotate their frame, statuses are logged,
    /// reach targets are commands.
    pub fn board(&mut self, t_us: u64, m: &BoardToHost) {
        match m {
            BoardToHost::Detection(d) => {
                if let Some(p) = self.pending.remove(&d.frame) {
                    self.annotate(p, Some(d));
                }
                let t = t_us * 1000;
                let head = ["HeadYaw", "HeadPitch"];
                self.push(t, "/board/head", msgs::JOINT_STATE, &write::joint_state(t, &head, &d.head.map(|v| v as f64)));
                if let (true, Some(r)) = (d.confirmed, d.reach) {
                    let names = msr_shared::joints::REACH_JOINTS.map(|j| j.name());
                    let t = t_us * 1000;
                    self.push(t, "/reach/target", msgs::JOINT_STATE, &write::joint_state(t, &names, &r.map(|v| v as f64)));
                }
            }
            BoardToHost::Status(s) => self.status(t_us, s),
            _ => {}
        }
    }

    /// A status (the board's, or any serializable value) at `t_us` on `/board/status`, its fields
    /// flattened into key-value pairs.
    pub fn status<T: Serialize>(&mut self, t_us: u64, s: &T) {
        let t = t_us * 1000;
        match write::diagnostics(t, "board status", "", 0, s) {
            Ok(d) => self.push(t, "/board/status", msgs::DIAGNOSTIC_ARRAY, &d),
            Err(e) => {
                self.error.get_or_insert(e.to_string());
            }
        }
    }

    /// Reported and commanded angles of named joints.
    pub fn joints(&mut self, t_us: u64, names: &[&str], reported: &[f64], commanded: &[f64]) {
        let t = t_us * 1000;
        self.push(t, "/joint_states", msgs::JOINT_STATE, &write::joint_state(t, names, reported));
        if !commanded.is_empty() {
            self.push(t, "/joint_commands", msgs::JOINT_STATE, &write::joint_state(t, names, commanded));
        }
    }

    /// A trial's outcome at its start.
    pub fn outcome<T: Serialize>(&mut self, t_us: u64, name: &str, v: &T, failed: bool) {
        let t = t_us * 1000;
        if let Ok(d) = write::diagnostics(t, name, if failed { "failed" } else { "" }, failed as u8, v) {
            self.push(t, "/msr/trial", msgs::DIAGNOSTIC_ARRAY, &d);
        }
    }

    /// Annotates the frames the board never answered; the first encoding error, if any.
    pub fn close(&mut self) -> Result<()> {
        self.saliency = None;
        for (_, p) in std::mem::take(&mut self.pending) {
            self.annotate(p, None);
        }
        match self.error.take() {
            Some(e) => anyhow::bail!("the MCAP log: {e}"),
            None => Ok(()),
        }
    }

    /// The time of the last message, ns.
    pub fn end_ns(&self) -> u64 {
        self.msgs.iter().map(|m| m.t_ns).max().unwrap_or(0)
    }
}

/// Writes logs one after the other (each shifted to start after the one before, with a 1 s gap),
/// each in time order, to `path`. Returns the messages written per topic.
pub fn write_logs<'a>(path: &Path, logs: impl IntoIterator<Item = &'a SessionLog>) -> Result<BTreeMap<String, u32>> {
    let mut out = McapLog::create(path)?;
    // ROS time 0 means "not set": start at 1 s.
    let mut base = 1_000_000_000u64;
    for log in logs {
        let mut order: Vec<&Logged> = log.msgs.iter().collect();
        order.sort_by_key(|m| m.t_ns);
        for m in order {
            out.add_raw(m.topic, m.type_name, base + m.t_ns, &shift(m, base)?)?;
        }
        base += log.end_ns() + 1_000_000_000;
    }
    let counts = out.counts();
    out.finish()?;
    Ok(counts)
}

/// The message with its stamps moved by `base` ns (stamps are in the CDR bytes: decode,
/// shift, encode).
fn shift(m: &Logged, base: u64) -> Result<Vec<u8>> {
    let t = |x: &mut msgs::Time| {
        if let Some(n) = x.to_ns() {
            *x = msgs::Time::from_ns(n + base);
        }
    };
    Ok(match m.type_name {
        msgs::IMAGE => {
            let mut v: msgs::Image = msgs::decode(&m.cdr)?;
            t(&mut v.header.stamp);
            msgs::encode(&v)?
        }
        msgs::JOINT_STATE => {
            let mut v: msgs::JointState = msgs::decode(&m.cdr)?;
            t(&mut v.header.stamp);
            msgs::encode(&v)?
        }
        msgs::DIAGNOSTIC_ARRAY => {
            let mut v: msgs::DiagnosticArray = msgs::decode(&m.cdr)?;
            t(&mut v.header.stamp);
            msgs::encode(&v)?
        }
        msgs::IMAGE_ANNOTATIONS => {
            let mut v: msgs::ImageAnnotations = msgs::decode(&m.cdr)?;
            v.circles.iter_mut().for_each(|c| t(&mut c.timestamp));
            v.points.iter_mut().for_each(|c| t(&mut c.timestamp));
            v.texts.iter_mut().for_each(|c| t(&mut c.timestamp));
            msgs::encode(&v)?
        }
        _ => m.cdr.clone(),
    })
}

impl SessionLog {
    /// Every servo's measured position (reported) and goal (commanded).
    pub fn servos(&mut self, t_us: u64, servos: &[msr_sim::servo::Servo]) {
        let names: Vec<&str> = servos.iter().map(|s| s.joint.name()).collect();
        let reported: Vec<f64> = servos.iter().map(|s| s.measured()).collect();
        let commanded: Vec<f64> = servos.iter().map(|s| s.target).collect();
        self.joints(t_us, &names, &reported, &commanded);
    }
}

/// A session's live output: the server and the model whose pipeline draws `/face/saliency`.
#[derive(Clone, Debug)]
pub struct LiveTap {
    /// The live view's server.
    pub live: std::sync::Arc<crate::live::Live>,
    /// The model blob whose pipeline draws `/face/saliency`.
    pub model: LogModel,
}

/// The model blob a mirror-test logs its saliency with (`EpisodeConfig::mcap`).
#[derive(Clone)]
pub struct LogModel(pub std::sync::Arc<[u8]>);

impl std::fmt::Debug for LogModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "LogModel({} bytes)", self.0.len())
    }
}
