//! The servo side: each control period's targets, the servos' states and positions, head moves.

use super::head::Settle;
use super::{Core, STATE_REQUEST_US};
use crate::dynamixel::{BusEvent, Polled};
use crate::model::ModelStore;
use crate::motion::{HeadError, PERIOD_US};
use embedded_io::Write;
use msr_shared::joints::REACH_JOINTS;
use msr_shared::msg::{
    BoardToHost, BoardToServo, ErrorCode, JointTarget, ServoBusKind, ServoBusReport,
};

impl<S: ModelStore> Core<S> {
    pub(super) fn on_states<H: Write>(
        &mut self,
        now_us: u64,
        states: &[msr_shared::msg::JointState],
        host: &mut H,
    ) {
        let mut any = false;
        let mut yaw = false;
        for s in states {
            if let Some(i) = REACH_JOINTS.iter().position(|j| *j == s.joint) {
                if s.position.is_finite() {
                    self.measured[i] = Some(s.position);
                    any = true;
                    yaw |= i == 0;
                }
            }
        }
        if any {
            self.feed_servos(now_us);
        }
        if yaw {
            self.gate_report(now_us, host);
        }
    }

    /// Fresh positions of the servos arrived: the watchdog is fed, streaming (re)starts.
    pub(super) fn feed_servos(&mut self, now_us: u64) {
        let recovered = self.servo_wd.feed(now_us);
        if self.motion.commanded().is_none() {
            if let [Some(a), Some(b), Some(c), Some(d), Some(e)] = self.measured {
                self.motion.start_from([a, b, c, d, e]);
                // After an outage the arm may be anywhere: finish by going home.
                if recovered {
                    self.motion.go_home();
                }
            }
        }
    }

    /// One control period.
    pub(super) fn tick<V: Write>(&mut self, now_us: u64, servo: &mut V) {
        if !self.bus_known {
            // Not a byte on a bus whose protocol is not known. The servo watchdog is armed by
            // the first positions only, so this silence trips nothing.
            return;
        }
        if self.dxl.is_some() {
            return self.tick_dynamixel(now_us, servo);
        }
        let time_ms = (now_us / 1000) as u32;
        let stale = self
            .servo_wd
            .last_us()
            .is_none_or(|t| now_us.saturating_sub(t) >= STATE_REQUEST_US);
        let asked = self
            .last_request_us
            .is_some_and(|t| now_us.saturating_sub(t) < STATE_REQUEST_US);
        if stale && !asked {
            self.servo_tx.send(servo, &BoardToServo::StateRequest);
            self.last_request_us = Some(now_us);
        }
        if self.servo_wd.tripped() {
            return; // Not streaming until the servos answer again.
        }
        let posture = if self.face_wd.tripped() {
            self.motion.hold_still()
        } else {
            self.motion.tick()
        };
        let Some(p) = posture else { return };
        if !self.stiffness_sent {
            self.stiffness_sent = self
                .servo_tx
                .send(servo, &BoardToServo::Stiffness { on: true });
        }
        let mut targets = heapless::Vec::new();
        for (j, a) in REACH_JOINTS.iter().zip(p) {
            // The last line of defence: only angles the joint table accepts are ever sent.
            match j.validate(a) {
                Ok(a) => {
                    let _ = targets.push(JointTarget {
                        joint: *j,
                        position: a,
                    });
                }
                Err(_) => self.counts.clamped_targets = self.counts.clamped_targets.saturating_add(1),
            }
        }
        self.servo_tx
            .send(servo, &BoardToServo::Targets { time_ms, targets });
    }

    /// One control period on the Dynamixel bus: goals for the posture (none while a watchdog
    /// holds or a servo reports a hardware error), and the positions read back.
    pub(super) fn tick_dynamixel<V: Write>(&mut self, now_us: u64, servo: &mut V) {
        let faulted = self.dxl.as_ref().is_some_and(|m| m.faulted());
        if faulted && !self.dxl_stopped {
            self.dxl_stopped = true;
            self.motion.stop();
        }
        let posture = if self.servo_wd.tripped() || faulted {
            None
        } else if self.face_wd.tripped() {
            self.motion.hold_still()
        } else {
            self.motion.tick()
        };
        let targets = posture.map(|p| {
            let mut t = [None; REACH_JOINTS.len()];
            for ((o, j), a) in t.iter_mut().zip(REACH_JOINTS).zip(p) {
                // Radians first; the master checks raw counts after conversion.
                match j.validate(a) {
                    Ok(a) => *o = Some(a),
                    Err(_) => self.counts.clamped_targets = self.counts.clamped_targets.saturating_add(1),
                }
            }
            t
        });
        if let Some(m) = self.dxl.as_mut() {
            m.period(now_us, servo, targets);
        }
    }

    pub(super) fn move_head<H: Write>(&mut self, now_us: u64, head: [f32; 2], host: &mut H) {
        // Head babbling sends no face frames: the request is the host's sign of life.
        self.face_wd.feed(now_us);
        let faulted = self.dxl.as_ref().is_some_and(|m| m.faulted());
        let result = if self.servo_wd.tripped() || faulted {
            Err(HeadError::NotStreaming)
        } else {
            self.motion.move_head(head)
        };
        match result {
            Ok(periods) => {
                let planned = periods as u64 * PERIOD_US;
                self.head.start(head, now_us, planned);
            }
            Err(e) => {
                let detail = match e {
                    HeadError::OutOfLimits => 0,
                    HeadError::NotStreaming => 1,
                    HeadError::Busy => 2,
                };
                self.error(host, ErrorCode::HeadRefused, detail);
            }
        }
    }

    /// After each control period: answers a head pose once the servos report it settled.
    pub(super) fn check_head<H: Write>(&mut self, now_us: u64, host: &mut H) {
        match self.head.check(now_us, &self.measured, &self.motion) {
            Settle::Idle => {}
            Settle::Settled => {
                let head = [self.measured[0].unwrap_or(0.0), self.measured[1].unwrap_or(0.0)];
                self.host_tx.send(host, &BoardToHost::HeadAt { head });
            }
            Settle::NotSettled(waited_ms) => self.error(host, ErrorCode::HeadNotSettled, waited_ms),
            // A move the host asked for is finished, not cut short by the face watchdog.
            Settle::Moving => {
                self.face_wd.feed(now_us);
            }
        }
    }

    /// What a Dynamixel poll brought: positions, and events for the host.
    pub(super) fn on_positions<H: Write>(&mut self, now_us: u64, polled: Polled, host: &mut H) {
        let yaw = polled.positions[0].is_some();
        for (m, p) in self.measured.iter_mut().zip(polled.positions) {
            if let Some(p) = p {
                *m = Some(p);
            }
        }
        while let Some(e) = self.dxl.as_mut().and_then(|m| m.event()) {
            let (code, detail) = match e {
                BusEvent::Ready => continue,
                BusEvent::Missing { id } => (ErrorCode::ServoMissing, id as u32),
                BusEvent::StartFailed { id, error } => (ErrorCode::ServoFault, id as u32 | (error as u32) << 16),
                BusEvent::Alert { id, hardware } => (ErrorCode::ServoFault, id as u32 | (hardware as u32) << 8),
                BusEvent::Lost { id } => (ErrorCode::ServoLost, id as u32),
            };
            self.error(host, code, detail);
        }
        // Only a Sync Read with every position feeds the watchdog: one silent servo is enough
        // to stop the motion once the watchdog's period has passed.
        if polled.complete {
            self.feed_servos(now_us);
        }
        if yaw {
            self.gate_report(now_us, host);
        }
    }

    pub(super) fn servo_bus_report(&self) -> ServoBusReport {
        let mut r = ServoBusReport {
            kind: ServoBusKind::Framed,
            running: false,
            servos: Default::default(),
            rx_errors: 0,
            busy_periods: 0,
        };
        // Before the host chose (see `Board::await_servo_bus`): framed, not running.
        if let Some(m) = &self.dxl {
            r.kind = ServoBusKind::Dynamixel;
            r.running = m.stage() == crate::dynamixel::Stage::Running;
            r.servos = *m.stats();
            r.rx_errors = m.rx_counters().errors();
            r.busy_periods = m.busy_periods;
        }
        r
    }
}
