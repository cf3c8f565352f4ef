//! One trial's scenario: the PC that shoots, crops and sends the camera frames, and the judge
//! of the reach.
use super::config::EpisodeConfig;
use super::scene::{Scene, SceneState};
use super::summary::{GateRecord, Trial};
use crate::data::crop;
use anyhow::{anyhow, Result};
use image::GrayImage;
use msr_shared::deliver::FaceLink;
use msr_shared::host_port::HostPort;
use msr_shared::msg::{BoardToHost, Detection, HostToBoard, Status};
use msr_sim::body::BodyPose;
use msr_sim::imperfect::Imperfections;
use msr_sim::light::{Light, LightSchedule};
use msr_sim::render::{Renderer, Variation};
use msr_sim::world::{self, Flow, World};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The reach is held when every reach joint is this close to its target.
pub const HELD_TOLERANCE_RAD: f64 = 0.01;
/// Frame period while the arm is up (detection paused; the face watchdog wants one per 500 ms).
pub const ARM_UP_FRAME_PERIOD_US: u64 = 250_000;
/// Joint samples for the judge: the DCM period.
pub const SAMPLE_US: u64 = 10_000;
/// How long after its line went idle the PC waits for the board's ack of a face-frame round
/// before polling again: two 1 ms ticks, the ack's bytes, a margin.
pub const FACE_ACK_TIMEOUT_US: u64 = 4_000;
/// A face frame still unfinished this many frame periods after it started is superseded by a
/// fresh camera frame (the face watchdog wants a whole frame every 500 ms).
pub const FACE_MAX_AGE_PERIODS: u64 = 2;

/// Renders and crops camera frames of one robot.
pub struct Camera<'a> {
    /// Draws the robot's frames (its looks, the light, the mark).
    pub renderer: &'a Renderer,
    /// The model's template and crop mode.
    pub cropper: &'a crop::Cropper,
}

impl Camera<'_> {
    /// The grey frame at a pose with an optional mark, and its face crop.
    pub fn shoot(
        &self,
        pose: &BodyPose,
        mark: Option<&msr_sim::marks::Mark>,
        rng: &mut ChaCha8Rng,
        light: Light,
    ) -> Result<(GrayImage, crop::Face)> {
        self.take([pose.head_yaw, pose.head_pitch], pose, mark, rng, light, &Imperfections::NONE, 0)
    }

    /// As [`Camera::shoot`] with the camera at head angles `camera` and the body in view at
    /// `seen` (another robot, or a delayed picture).
    pub fn shoot_seen(
        &self,
        camera: [f64; 2],
        seen: &BodyPose,
        mark: Option<&msr_sim::marks::Mark>,
        rng: &mut ChaCha8Rng,
        light: Light,
    ) -> Result<(GrayImage, crop::Face)> {
        self.take(camera, seen, mark, rng, light, &Imperfections::NONE, 0)
    }

    /// As [`Camera::shoot_seen`], the frame taken through `through` (frame number `frame` for
    /// its noise).
    #[allow(clippy::too_many_arguments)]
    pub fn take(
        &self,
        camera: [f64; 2],
        seen: &BodyPose,
        mark: Option<&msr_sim::marks::Mark>,
        rng: &mut ChaCha8Rng,
        light: Light,
        through: &Imperfections,
        frame: u64,
    ) -> Result<(GrayImage, crop::Face)> {
        let var = Variation::random(rng).lit(light);
        let full = [0, 0, msr_sim::body::WIDTH, msr_sim::body::HEIGHT];
        let mut r = self.renderer.render_seen(camera, seen, mark, &var, full);
        if !through.is_none() {
            r.rgb = through.apply(&r.rgb, frame);
        }
        let grey = crop::grey_of(&r.rgb);
        let face = self.cropper.crop_colour(&grey, &r.rgb)?;
        Ok((grey, face))
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Stage {
    Watching,
    /// A reach started at this time, towards this target.
    Reaching {
        since_us: u64,
    },
    Held {
        since_us: u64,
    },
    Done,
}

/// The scenario of one trial: the PC and the judge.
struct Scenario<'a> {
    cfg: &'a EpisodeConfig,
    camera: Camera<'a>,
    /// Camera noise: how many frames are shot depends on the link.
    rng: ChaCha8Rng,
    /// The mark alone, on a stream of its own, so that a noisy link (more or fewer frames shot
    /// before the mark) does not change which mark a seed draws.
    mark_rng: ChaCha8Rng,
    scene: SceneState,
    port: HostPort,
    /// Face frames out, with selective repeat.
    faces: FaceLink,
    /// The frame id of the reach last seen (the board repeats it while the arm is up).
    last_reach_frame: Option<u16>,
    marked: bool,
    mark: Option<msr_sim::marks::Mark>,
    next_frame_us: u64,
    next_sample_us: u64,
    stage: Stage,
    target: Option<[f32; 5]>,
    held: Vec<msr_sim::kin::Reach>,
    trial: Trial,
    error: Option<anyhow::Error>,
    status: Option<Status>,
    detections: Vec<(u64, Detection)>,
    /// Frames sent while the mark was on the face.
    frames_with_mark: usize,
    log: Option<crate::rosbag::session::SessionLog>,
    /// The trial's light (and the camera's gain loop).
    light: LightSchedule,
    /// Where the trial starts in `light` (a plan that spans a run of trials).
    light_offset_us: u64,
    /// The camera's imperfections, seeded for this trial.
    imperfect: Imperfections,
    /// When the last frame was taken and the camera's head angles then (for the motion blur).
    last_shot: Option<(u64, [f64; 2])>,
}

impl Scenario<'_> {
    fn mark_on(&self, now: u64) -> bool {
        self.marked && now >= self.cfg.mark_at_us
    }

    fn step(&mut self, w: &mut World) -> Result<Flow> {
        let now = w.now_us;
        self.scene.step(now, &w.body_pose());
        if now == 0 {
            // The bus first: the board (in-process or QEMU) says nothing on it until told.
            let bytes = self.port.encode(&HostToBoard::UseServoBus(self.cfg.servo_bus.kind()));
            w.host.send(&bytes);
            if let Some(c) = self.cfg.board_config {
                let bytes = self.port.encode(&HostToBoard::Configure(c));
                w.host.send(&bytes);
            }
            if !self.cfg.learn_room {
                let bytes = self.port.encode(&HostToBoard::Room(msr_shared::msg::RoomCommand::Freeze));
                w.host.send(&bytes);
            }
        }
        let msgs = self.port.receive(&w.host.receive());
        self.port.check_version()?;
        for m in msgs {
            if let Some(l) = &mut self.log {
                l.board(now, &m);
            }
            self.faces.on_message(&m);
            match m {
                BoardToHost::Detection(d) => {
                    if d.confirmed && self.last_reach_frame == Some(d.frame) {
                        continue; // The reach again, while the arm is up.
                    }
                    if d.blob.is_some() {
                        self.trial.detections += 1;
                    }
                    match d.reason {
                        Some(msr_shared::msg::NoDetection::NoFace) => self.trial.no_face_frames += 1,
                        Some(msr_shared::msg::NoDetection::SceneChanged) => self.trial.scene_changed_frames += 1,
                        None => {}
                    }
                    if d.confirmed {
                        self.last_reach_frame = Some(d.frame);
                        self.on_reach(now, d);
                    }
                    self.detections.push((now, d));
                }
                BoardToHost::Status(s) => self.status = Some(s),
                BoardToHost::SelfGate(g) => self.trial.gate.push(GateRecord::of(now, &g)),
                _ => {}
            }
        }
        if self.trial.false_reach {
            return Ok(Flow::Stop);
        }
        // The mark appears: choose one that shows, at the pose the head has now.
        if self.mark_on(now) && self.mark.is_none() {
            // On the other robot's face in the other scene.
            let on = match self.scene.scene {
                Scene::Other => self.scene.view(now, &w.body_pose()).seen,
                _ => w.body_pose(),
            };
            let (m, _) = msr_sim::dataset::render_marked(
                self.camera.renderer,
                &on,
                &Variation::CLEAN,
                &mut self.mark_rng,
            );
            let p = msr_sim::body::project_head(&m.point_head(), 0.0, 0.0);
            self.trial.mark = Some(format!("{} {}", m.colour, m.kind));
            self.trial.mark_pixel = p;
            self.mark = Some(m);
        }
        let arm_up = !matches!(self.stage, Stage::Watching);
        let period = if arm_up {
            ARM_UP_FRAME_PERIOD_US.max(self.cfg.frame_period_us)
        } else {
            self.cfg.frame_period_us
        };
        // A new camera frame once the last one is through (or has taken too long: superseded).
        let ready = match self.faces.in_flight_since() {
            None => w.host.tx_idle_at_us() <= now,
            Some(t) => now.saturating_sub(t) >= FACE_MAX_AGE_PERIODS * period,
        };
        if now >= self.next_frame_us && ready {
            let light = self.light.at(now + self.light_offset_us);
            let pose = w.body_pose();
            let (head, seen, mark) = if self.scene.scene == Scene::Mirror {
                ([pose.head_yaw, pose.head_pitch], pose, self.mark.as_ref())
            } else {
                let v = self.scene.view(now, &pose);
                // A delayed picture shows the mark once it had appeared by then.
                (v.camera, v.seen, self.mark.as_ref().filter(|_| v.as_of_us >= self.cfg.mark_at_us))
            };
            // The head's speed since the last frame smears this one.
            let speed = match self.last_shot {
                Some((t, h)) if now > t => {
                    let dt = (now - t) as f64 * 1e-6;
                    [(head[0] - h[0]) / dt, (head[1] - h[1]) / dt]
                }
                _ => [0.0; 2],
            };
            self.last_shot = Some((now, head));
            let through = self.imperfect.moving(speed);
            let frame = self.trial.frames_sent as u64;
            let (grey, face) = self.camera.take(head, &seen, mark, &mut self.rng, light, &through, frame)?;
            self.light.observed_grey(&grey);
            let with_mark = mark.is_some();
            let logged = self.log.is_some().then(|| face.clone());
            let c = face.crop;
            let size = [c.width as u16, c.height as u16];
            // The sub-pixel part too: the self gate follows the face to a fraction of a pixel.
            let at = msr_shared::msg::CropAt::subpixel([c.x as u16, c.y as u16], face.at);
            let id = self.faces.start(at, size, face.image(), now);
            if let Some(f) = logged {
                self.log_frame(now, id, w, &grey, &f, with_mark);
            }
            self.trial.frames_sent += 1;
            if with_mark {
                self.frames_with_mark += 1;
            }
            self.next_frame_us = now + period;
        }
        self.faces.check(now);
        let mut bytes = Vec::new();
        let port = &mut self.port;
        self.faces.pump(|m| bytes.extend(port.encode(m)));
        if !bytes.is_empty() {
            w.host.send(&bytes);
        }
        self.faces.sent(w.host.tx_idle_at_us());
        if now >= self.next_sample_us {
            self.next_sample_us = now + SAMPLE_US;
            self.sample(now, w);
            if let Some(l) = &mut self.log {
                l.servos(now, w.servos.servos());
            }
        }
        let limit = match self.stage {
            Stage::Watching => self.cfg.mark_at_us + self.cfg.watch_us,
            _ => self.cfg.max_us(),
        };
        Ok(if self.stage == Stage::Done || now >= limit {
            Flow::Stop
        } else {
            Flow::Continue
        })
    }

    /// Logs a frame sent (`--mcap`), with the mark's box from a clean render of the same view.
    fn log_frame(&mut self, now: u64, id: u16, w: &World, grey: &GrayImage, face: &crop::Face, with_mark: bool) {
        let r = self.camera.renderer;
        let truth = match (with_mark, self.scene.scene) {
            (false, _) => None,
            (true, Scene::Mirror) => r.render(&w.body_pose(), self.mark.as_ref(), &Variation::CLEAN).mark,
            (true, _) => {
                let v = self.scene.view(now, &w.body_pose());
                let full = [0, 0, msr_sim::body::WIDTH, msr_sim::body::HEIGHT];
                r.render_seen(v.camera, &v.seen, self.mark.as_ref(), &Variation::CLEAN, full).mark
            }
        };
        let truth = truth.filter(|m| m.pixels > 0).map(|m| m.box_xyxy);
        let q = w.servos.reach_angles();
        if let Some(l) = &mut self.log {
            l.frame(now, id, grey, face, truth, [q[0] as f32, q[1] as f32]);
        }
    }

    fn on_reach(&mut self, now: u64, d: Detection) {
        self.trial.reached = true;
        if !self.mark_on(now) {
            self.trial.false_reach = true;
            self.trial.reach_target = d.reach;
            return;
        }
        if self.trial.latency_ms.is_none() {
            self.trial.latency_ms = Some((now - self.cfg.mark_at_us) as f64 / 1000.0);
        }
        self.target = d.reach;
        self.trial.reach_target = d.reach;
        self.held.clear();
        self.stage = Stage::Reaching { since_us: now };
    }

    fn sample(&mut self, now: u64, w: &World) {
        let q = w.servos.reach_angles();
        let Some(t) = self.target else { return };
        let near = q
            .iter()
            .zip(t)
            .all(|(a, b)| (a - b as f64).abs() <= HELD_TOLERANCE_RAD);
        match self.stage {
            Stage::Reaching { .. } if near => {
                self.stage = Stage::Held { since_us: now };
                self.held.push(q);
            }
            Stage::Held { since_us } => {
                if !near {
                    // The board left the target early (a watchdog): not a held reach.
                    self.stage = Stage::Watching;
                    self.trial.failure =
                        Some("the arm left the reach target before the hold was judged".into());
                    self.held.clear();
                } else {
                    self.held.push(q);
                    if now - since_us >= self.cfg.judge_hold_us {
                        self.judge();
                        self.stage = Stage::Done;
                    }
                }
            }
            _ => {}
        }
    }

    fn judge(&mut self) {
        let Some(m) = &self.mark else { return };
        if self.scene.scene == Scene::Other {
            // The mark is on the other robot: whatever the hand touched, it was the wrong face.
            self.trial.failure = Some("other: reached for its own face; the mark is on the other robot".into());
            return;
        }
        let radius_m = self.cfg.touch_radius_mm / 1000.0;
        let (touched, worst) = msr_sim::kin::judge_touch_of(&self.held, &m.point_head(), &self.cfg.arm_error, radius_m);
        self.trial.touched = touched;
        self.trial.touch_error_mm = Some(worst * 1000.0);
        if !touched {
            self.trial.failure = Some(format!("reach held {:.1} mm from the mark", worst * 1000.0));
        }
    }

    /// Why a marked trial did not touch, from what the board reported.
    fn diagnose(&self) -> Option<String> {
        if !self.marked || self.trial.touched {
            return None;
        }
        if self.mark.is_none() {
            return Some(if self.trial.false_reach {
                "ended before the mark appeared: a false reach".into()
            } else {
                "ended before the mark appeared".into()
            });
        }
        if let Some(f) = &self.trial.failure {
            return Some(f.clone());
        }
        let after: Vec<&Detection> = self
            .detections
            .iter()
            .filter(|(t, _)| *t >= self.cfg.mark_at_us)
            .map(|(_, d)| d)
            .collect();
        let seen = after.iter().filter(|d| d.blob.is_some()).count();
        let sent = self.frames_with_mark;
        // Frames the board never answered were lost on the link, not missed by detection.
        let lost = sent.saturating_sub(after.len());
        Some(match (self.stage, seen) {
            _ if after.is_empty() => {
                format!("link: no answer from the board to any of the {sent} frames with the mark")
            }
            (_, 0) if lost > 0 => format!(
                "detection: no blob in the {} answered frames with the mark \
                 (link: {lost} of {sent} got no answer)",
                after.len()
            ),
            (_, 0) => format!("detection: no blob in {} frames with the mark", after.len()),
            (Stage::Watching, n) => format!("confirm: blob in only {n} of {} frames", after.len()),
            (Stage::Reaching { .. }, _) => {
                "motion: the arm never settled at the reach target".into()
            }
            _ => "unknown".into(),
        })
    }
}

/// Runs one trial with any firmware; returns the trial (with the sim side's counters) and the
/// last status the board sent, if any.
pub fn run_trial_with<F: world::Firmware>(
    fw: &mut F,
    camera: Camera,
    cfg: &EpisodeConfig,
    index: usize,
    seed: u64,
) -> Result<(Trial, Option<Status>)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let marked = !rng.gen_bool(cfg.no_mark_share.clamp(0.0, 1.0));
    let mut mark_rng = ChaCha8Rng::seed_from_u64(seed);
    mark_rng.set_stream(1);
    let mut scene_rng = ChaCha8Rng::seed_from_u64(seed);
    scene_rng.set_stream(2);
    let scene = SceneState::new(cfg.scene, scene_rng);
    let (delay_us, babbles) = (scene.delay_us, scene.babbles);
    // On a stream of its own: the fixed light's trials keep their draws.
    let mut light_rng = ChaCha8Rng::seed_from_u64(seed);
    light_rng.set_stream(3);
    let (light, light_offset_us) = match cfg.light_span {
        Some(r) => (LightSchedule::new(cfg.light, r.span_us, &mut ChaCha8Rng::seed_from_u64(r.seed)), r.offset_us),
        None => (LightSchedule::new(cfg.light, cfg.mark_at_us + cfg.watch_us, &mut light_rng), 0),
    };
    let mut sc = Scenario {
        cfg,
        camera,
        rng,
        mark_rng,
        scene,
        port: HostPort::default(),
        faces: FaceLink::new(FACE_ACK_TIMEOUT_US),
        last_reach_frame: None,
        marked,
        mark: None,
        next_frame_us: 0,
        next_sample_us: 0,
        stage: Stage::Watching,
        target: None,
        held: Vec::new(),
        trial: Trial {
            index,
            scene: cfg.scene.name().into(),
            delay_ms: (cfg.scene == Scene::Delayed).then(|| delay_us as f64 / 1000.0),
            other_babbles: (cfg.scene == Scene::Other).then_some(babbles),
            arm_error: (!cfg.arm_error.is_exact()).then_some(cfg.arm_error),
            ..Default::default()
        },
        error: None,
        status: None,
        detections: Vec::new(),
        frames_with_mark: 0,
        log: crate::rosbag::session::SessionLog::for_episode(cfg.mcap.as_ref(), cfg.live.as_ref()),
        light,
        light_offset_us,
        imperfect: cfg.camera.with_seed(seed ^ 0xCA3E_7A01),
        last_shot: None,
    };
    let wcfg = cfg.world(seed);
    let (w, report) = world::run(
        &wcfg,
        fw,
        |w: &mut World| match sc.step(w) {
            Ok(f) => f,
            Err(e) => {
                sc.error = Some(e);
                Flow::Stop
            }
        },
        cfg.max_us(),
    )
    .map_err(|e| anyhow!("trial {index}: {e}"))?;
    if let Some(e) = sc.error.take() {
        return Err(e.context(format!("trial {index}")));
    }
    sc.trial.failure = sc.diagnose();
    sc.trial.ended_before_mark = sc.marked && sc.mark.is_none();
    let mut t = sc.trial.clone();
    t.limit_violations = w.servos.counters().limit_violations;
    t.link = sc.faces.stats;
    let bus = w.servos.frame_counters();
    let pc = sc.port.counters();
    t.crc_errors = bus.crc_errors + pc.crc_errors;
    t.resyncs = bus.resyncs() + pc.resyncs();
    if let Some(d) = w.servos.dynamixel() {
        // The servos refuse a Goal Position outside their limits; either way it is counted.
        t.limit_violations += d.counters().limit_violations;
        t.crc_errors += d.rx_counters().crc_errors;
        t.resyncs += d.rx_counters().errors() - d.rx_counters().crc_errors;
    }
    t.sim_s = report.end_us as f64 * 1e-6;
    t.wall_s = report.wall_s;
    if let Some(mut l) = sc.log.take() {
        l.outcome(0, &format!("trial {index}"), &t, (t.mark.is_some() && !t.touched) || t.false_reach);
        l.close()?;
        t.log = Some(l);
    }
    Ok((t, sc.status))
}
