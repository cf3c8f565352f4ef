//! A face frame through the pipeline, confirmation and self gate to a detection or a reach.

use super::head::held;
use super::{Core, ROOM_SAVE_MS};
use crate::light::Verdict;
use crate::model::ModelStore;
use crate::motion::Phase;
use crate::pipeline::{self, Workspace};
use crate::self_gate::Step;
use embedded_io::Write;
use msr_shared::blob::Model;
use msr_shared::msg::{
    BlobReport, BoardToHost, Detection, ErrorCode, FrameHeader, GateUndecided, NoDetection,
    RoomState,
};

impl<S: ModelStore> Core<S> {
    pub(super) fn on_frame<H: Write>(
        &mut self,
        now_us: u64,
        h: FrameHeader,
        pixels: &[u8],
        ws: &mut Workspace,
        host: &mut H,
    ) {
        self.counts.frames = self.counts.frames.saturating_add(1);
        // The grey face, then its chroma planes when the frame carries them.
        let (pixels, planes) = pixels.split_at(h.pixels().min(pixels.len()));
        let planes = h.colour.then_some(planes);
        if self.face_wd.feed(now_us) {
            self.motion.go_home();
        }
        if self.motion.phase() == Phase::Probe {
            // The probe's frames go to the gate only: no reach while the head moves.
            let step = match (self.measured[0], self.measured[1]) {
                (Some(yaw), Some(pitch)) => {
                    let head = self.steady.pose([yaw, pitch]);
                    let salient = match (self.settings, self.store.active()) {
                        (Some(s), Some(bytes)) => Model::parse_trusted(bytes).ok().and_then(|m| {
                            pipeline::detect_colour(ws, &m, &s, pixels, planes, [h.crop_x, h.crop_y], head).ok()
                        }),
                        _ => None,
                    };
                    let face = salient.as_ref().is_some_and(|d| d.light.verdict == Verdict::Face);
                    let salient = salient.map_or(u32::MAX, |d| d.salient_pixels);
                    match self.gate.as_mut() {
                        Some(g) => g.on_probe_frame(now_us, h.frame, h.position(), salient, face),
                        None => Step::Wait,
                    }
                }
                _ => Step::Wait,
            };
            self.gate_step(now_us, step, h.frame, host);
            return;
        }
        if self.motion.arm_up() {
            // Detection pauses while the arm is up; the reach is reported again.
            if let Some(d) = self.last_reach {
                self.host_tx.send(host, &BoardToHost::Detection(d));
            }
            return;
        }
        self.last_reach = None;
        let (Some(yaw), Some(pitch)) = (self.measured[0], self.measured[1]) else {
            self.error(host, ErrorCode::ServoTimeout, 1);
            return;
        };
        let head = [yaw, pitch];
        let steady = self.steady.pose(head);
        if self.store.busy() {
            // On a board the model's flash bank may be being erased: reading it would stall the
            // CPU (and the control period) until the erase ends. The next frame is read.
            self.error(host, ErrorCode::StoreBusy, 1);
            return;
        }
        let result = match (self.settings, self.store.active()) {
            (Some(settings), Some(bytes)) => match Model::parse_trusted(bytes) {
                Ok(model) => {
                    pipeline::detect_colour(ws, &model, &settings, pixels, planes, [h.crop_x, h.crop_y], steady)
                        .map_err(|_| (ErrorCode::BadFrame, h.frame as u32))
                }
                Err(_) => Err((ErrorCode::NoModel, 1)),
            },
            _ => Err((ErrorCode::NoModel, 0)),
        };
        let det = match result {
            Ok(d) => d,
            Err((code, detail)) => {
                self.error(host, code, detail);
                return;
            }
        };
        if det.blob.is_some() {
            self.counts.detections = self.counts.detections.saturating_add(1);
        }
        let reason = match det.light.verdict {
            Verdict::Face => None,
            Verdict::NoFace => {
                self.counts.no_face = self.counts.no_face.saturating_add(1);
                Some(NoDetection::NoFace)
            }
            Verdict::SceneChanged => {
                self.counts.scene_changed = self.counts.scene_changed.saturating_add(1);
                Some(NoDetection::SceneChanged)
            }
        };
        if let Some(g) = self.gate.as_mut() {
            g.observe(h.position(), yaw, det.salient_pixels);
        }
        let mut confirmed = false;
        let held = held(head, self.motion.head_goal());
        if self.confirm.push(det.blob.is_some())
            && !self.servo_wd.tripped()
            && !self.face_wd.tripped()
        {
            if let (Some(target), Some(g)) = (det.reach, self.gate.as_mut()) {
                // Not yet: first the probe that tells whether this face is ours.
                self.confirm.reset();
                let step = g.start(now_us, h.frame, held, target);
                self.gate_step(now_us, step, h.frame, host);
            } else if let Some(target) = det.reach {
                if self.motion.reach(target) {
                    confirmed = true;
                    self.counts.reaches = self.counts.reaches.saturating_add(1);
                    self.counts.clamped_targets = self.counts.clamped_targets.saturating_add(det.reach_clamped);
                    self.confirm.reset();
                }
            }
        }
        // Online self-calibration, never on a frame that paid for a new prediction (rule 1):
        // the frame's budget has no room for both. Rule 3 on the next frame after a batch's
        // last, whatever it shows: that frame is not learnt from, so the update's cost and the
        // samples' never share one. Else rule 1: only a face with nothing on it, no candidate
        // being confirmed, observing with the head still.
        let held = !ws.afresh();
        if held && ws.room.pending() {
            self.room_unsaved |= ws.room.settle();
            self.room = ws.room.report(self.room_applies());
        } else if held
            && reason.is_none()
            && det.blob.is_none()
            && self.confirm.quiet()
            && self.motion.phase() == Phase::Observe
            && !self.head.moving()
            && self.room.state == RoomState::Learning
        {
            if let Some(m) = self.store.active().and_then(|b| Model::parse_trusted(b).ok()) {
                self.room_unsaved |= ws.learn(&m, pixels, now_us);
                self.room = ws.room.report(true);
            }
        }
        let now_ms = now_us / 1000;
        if self.room_unsaved && now_ms.saturating_sub(self.room_saved_ms) >= ROOM_SAVE_MS {
            self.save_room(ws, now_ms);
        }
        let blob = det.blob.zip(det.centroid).map(|(b, c)| BlobReport {
            area: b.area,
            box_xyxy: [
                b.x0.saturating_add(h.crop_x),
                b.y0.saturating_add(h.crop_y),
                b.x1.saturating_add(h.crop_x),
                b.y1.saturating_add(h.crop_y),
            ],
            centroid: c,
        });
        let d = Detection {
            frame: h.frame,
            head,
            blob,
            confirmed,
            reach: det.reach,
            reason,
        };
        if confirmed {
            self.last_reach = Some(d);
        }
        self.host_tx.send(host, &BoardToHost::Detection(d));
    }

    /// Carries out what the self gate asks: a head pose, or its decision (reported on the host
    /// link; a pass starts the reach as a confirmed detection of `frame`, anything else goes home).
    pub(super) fn gate_step<H: Write>(&mut self, now_us: u64, step: Step, frame: u16, host: &mut H) {
        match step {
            Step::Wait => {}
            Step::Head(head) => {
                if !self.motion.probe(head) {
                    // Not streaming (the servos went quiet just now): undecided.
                    if let Some(g) = self.gate.as_mut() {
                        let s = g.abort(now_us, GateUndecided::ServosSilent);
                        self.gate_step(now_us, s, frame, host);
                    }
                }
            }
            Step::Done(report, target) => {
                self.host_tx.send(host, &BoardToHost::SelfGate(report));
                match target {
                    Some(t) if self.motion.reach(t) => {
                        self.counts.reaches = self.counts.reaches.saturating_add(1);
                        let head = [self.measured[0].unwrap_or(f32::NAN), self.measured[1].unwrap_or(f32::NAN)];
                        let d = Detection { frame, head, blob: None, confirmed: true, reach: Some(t), reason: None };
                        self.last_reach = Some(d);
                        self.host_tx.send(host, &BoardToHost::Detection(d));
                    }
                    _ => self.motion.go_home(),
                }
            }
        }
    }

    /// A fresh report of the head's yaw (this poll's servo status, not the last one kept): to
    /// the gate, which averages the reports at rest and at each probe pose. Fresh only: a poll
    /// runs as often as its loop does (each sim tick, unpaced on a board), not once a report.
    pub(super) fn gate_report<H: Write>(&mut self, now_us: u64, host: &mut H) {
        let (Some(yaw), Some(g)) = (self.measured[0], self.gate.as_mut()) else { return };
        let step = g.on_servo(now_us, yaw);
        let frame = self.last_reach.map_or(0, |d| d.frame);
        self.gate_step(now_us, step, frame, host);
    }

    /// While probing: the ways a probe ends without frames (a watchdog, a bus fault, the
    /// timeout).
    pub(super) fn gate_watch<H: Write>(&mut self, now_us: u64, host: &mut H) {
        self.last_poll_us = now_us;
        let Some(g) = self.gate.as_mut() else { return };
        if !g.probing() {
            return;
        }
        let faulted = self.dxl.as_ref().is_some_and(|m| m.faulted());
        let step = if self.servo_wd.tripped() || faulted || self.motion.commanded().is_none() {
            g.abort(now_us, GateUndecided::ServosSilent)
        } else if self.face_wd.tripped() {
            g.abort(now_us, GateUndecided::FaceLost)
        } else {
            g.poll(now_us)
        };
        let frame = self.last_reach.map_or(0, |d| d.frame);
        self.gate_step(now_us, step, frame, host);
    }
}
