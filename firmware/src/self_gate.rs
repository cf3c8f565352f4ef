//! The self gate: is the face in view the robot's own mirror image?
//!
//! Contingency, as in developmental psychology: my image moves when and as I move. Before a
//! confirmed mark may start a reach, the head turns by `+amplitude` in yaw, then `-amplitude`
//! (from the resting yaw; by way of [`VIA_RAD`] below it, so that every pose is approached
//! from below and a servo that friction stops short stops as short at each), and at each probe
//! pose, once the servos report it settled and the robot's own latency has passed, the face crop's x position (every frame header carries it,
//! to 1/64 pixel) is averaged over `min_frames` frames, and the head's reported yaw over every
//! servo report meanwhile. Then
//!
//! - `gain_ratio = ((x+ - x-) / (2 amplitude)) / gain`, against the gain of the robot's own
//!   mirror image (calibrated from rendered frames and stored in the model blob): in a mirror
//!   the face and the camera turn together, so the face shifts by the camera's turn alone;
//!   anything else (another robot, a still picture) shifts by a different amount, and a
//!   delayed picture shows the probe's poses late, so not at all or backwards;
//! - `rest_px`: the resting face (frames before the probe) must lie on the probe's line, midway
//!   between the poses, or as far from there as the encoder says the head rested from the
//!   poses' midpoint (the rest was approached from either side);
//!
//! - `hold_px`: the largest range of x over the resting frames and over each pose's frames
//!   (the head holds still then; so does its image, and a robot babbling its head does not);
//! - `level_px`: how far the face's y moved at a pose from its rest (a yaw probe does not move
//!   the own image up or down; a babbling robot's pitch does);
//! - `line_px` (a gate with [`SelfGate::line_tol`], blob layout 2): the probe ends with a third
//!   stage back at the resting yaw the probe started from, the poses' exact midpoint (the servo
//!   goes where it is sent, or stops as short of it as of the poses, all approached from
//!   below), and the face there must lie on the poses' line. The board starts
//!   the probe from where the head was sent while its servos report it near there (within
//!   `board::HOLD_RAD`, eight counts), else from the reported angles: a probe centred on a
//!   reading that encoder noise or a sagging pitch servo moved off the goal would move the head
//!   by those counts, in pitch too. `rest_px` carries
//!   the servo's rounding of the resting pose (up to half a pixel), so it cannot be tight;
//!   `line_px` carries only the template match's noise. Another robot that stands still at a
//!   pose whose camera-only gain happens to match the own image's, or that moved a little
//!   between the rest and the probe, lies off the line by a few tenths of a pixel (a
//!   gate without this stage passed such babblers 4 times in 200 red trials). The same gate also wants the face the
//!   model predicts at every probe frame: the pipeline's light fit finds it ([`crate::light`]'s
//!   verdict `Face`). The own image turns with the head as the decoder predicts; another robot's
//!   face does not, and at a pose where it matches the prediction too badly the fit refuses it
//!   (`unlike` counts those frames; its salient pixels read 0). And the mark it is about to
//!   reach for must turn with the face: salient pixels at one pose at least (the own image's
//!   mark stays on its face; another robot's can leave the crop or its prediction).
//!
//! Pass when `|gain_ratio - 1| <= gain_tol`, `rest_px <= rest_tol`, `hold_px <= hold_tol` and
//! `level_px <= level_tol` (and `line_px <= line_tol` with a return stage): the own image lies on its line at every frame of the probe, to the
//! precision calibration measured for each statistic (a layout-0 blob has one tolerance for
//! all three); and, with a joint bound (`SelfGate::joint_tol`, blob layout 3), when the
//! statistics' squared shares of their tolerances sum to at most it ([`joint`]): near one
//! tolerance is the own image's noise, near several at once a stranger's luck (a babbling
//! robot that held still at a pose whose gain came within the band passes a box of separate
//! tolerances about 3 times in 1200 red trials). A probe starts only after the head has rested
//! [`REST_BEFORE_PROBE_US`] since the last one: a delayed picture of the last probe must not
//! replay in step with the next. Anything that stops the
//! test (no frames, silent servos, a head that does not get there, the timeout) is undecided,
//! and undecided never reaches. Memory: a few floats, fixed.

use msr_shared::blob::SelfGate;
use msr_shared::msg::{GateDecision, GateReport, GateUndecided};

/// Resting frames kept (the latest, before a probe): their mean face x is the rest the probe's
/// line must pass, their mean reported yaw (each frame's the mean of the servo reports since
/// the frame before) where the encoder says the head rested (`drift`).
/// Three: since each frame's yaw is the mean of the reports before it, three frames carry
/// about thirty readings, and at one count RMS of encoder noise they refuse no own image, as
/// six did (six were needed while each frame had one reading). Older frames can predate the
/// mark (confirmation needs three frames with it) and a mark moves the template match by a
/// fraction of a pixel: over six, seed 9002 refused one of red's own images on it. A probe
/// that starts with fewer takes those it has.
pub const REST_FRAMES: usize = 3;

/// The most servo reports a resting frame's yaw averages (ten a frame in the episodes): when
/// frames stop while the reports go on (a camera unplugged), the sum starts again, and the
/// first frame back takes the latest few, not minutes of them.
pub const REST_REPORTS: u16 = 64;

/// What the board does next.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Step {
    /// Keep going.
    Wait,
    /// Move the head to `[yaw, pitch]`.
    Head([f32; 2]),
    /// Decided: report it; reach `target` only when it passed.
    Done(GateReport, Option<[f32; 5]>),
}

#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Acc {
    x: f32,
    /// Range of x over the frames (the face must hold still while the head does).
    x_min: f32,
    x_max: f32,
    y: f32,
    /// Sum of the servos' yaw reports over the pose's window ([`Gate::on_servo`]).
    yaw: f32,
    salient: f32,
    n: u8,
    /// Frames in which the pipeline did not find the predicted face.
    unlike: u8,
    /// Yaw reports summed (in the struct's padding).
    reports: u8,
}

impl Acc {
    /// One servo report at the pose; past 255 the mean is that of the first 255.
    fn report(&mut self, yaw: f32) {
        if self.reports < u8::MAX {
            self.yaw += yaw;
            self.reports += 1;
        }
    }
    fn push(&mut self, x: f32, y: f32, salient: u32, face: bool) {
        self.unlike = self.unlike.saturating_add(!face as u8);
        if self.n == 0 {
            (self.x_min, self.x_max) = (x, x);
        }
        self.x_min = self.x_min.min(x);
        self.x_max = self.x_max.max(x);
        self.x += x;
        self.y += y;
        self.salient += salient as f32;
        self.n = self.n.saturating_add(1);
    }
    /// Mean x of the frames and mean reported yaw (NaN without a report: undecided).
    fn mean(&self) -> (f32, f32) {
        let yaw = if self.reports == 0 { f32::NAN } else { self.yaw / self.reports as f32 };
        (self.x / self.n.max(1) as f32, yaw)
    }
    fn y(&self) -> f32 {
        self.y / self.n.max(1) as f32
    }
    fn salient(&self) -> f32 {
        self.salient / self.n.max(1) as f32
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Probe {
    started_us: u64,
    target: [f32; 5],
    /// Resting face x, yaw and salient pixels.
    rest: (f32, f32, f32),
    /// Resting face y, and the range of the resting face x.
    rest_y: f32,
    /// The resting frames' mean reported yaw.
    rest_yaw: f32,
    rest_spread: f32,
    pitch: f32,
    /// 0: the `+amplitude` pose, 1: the `-amplitude` pose, 2: back at the rest (return stage).
    stage: u8,
    /// On the way to stage 1 by way of [`VIA_RAD`] below its pose.
    via: bool,
    settled_since: Option<u64>,
    acc: [Acc; 3],
    last_frame: u16,
}

impl Probe {
    /// Settled at the current pose and `latency_us` past it: frames and servo reports count.
    fn counting(&self, now_us: u64, latency_us: u64) -> bool {
        self.settled_since.is_some_and(|t| now_us >= t.saturating_add(latency_us))
    }
}

/// The gate of one model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gate {
    p: SelfGate,
    /// Latest resting frames: (face x, yaw, salient pixels), newest last, and their face y.
    rest: [(f32, f32, f32); REST_FRAMES],
    rest_y: [f32; REST_FRAMES],
    /// When the last probe ended.
    last_end_us: Option<u64>,
    rest_n: u8,
    /// Yaw reports since the last resting frame: their sum and count (that frame's yaw).
    pending: (f32, u16),
    probe: Option<Probe>,
}

impl Gate {
    /// A gate with the blob's parameters, nothing seen yet.
    pub const fn new(p: SelfGate) -> Gate {
        Gate {
            p,
            rest: [(0.0, 0.0, 0.0); REST_FRAMES],
            rest_y: [0.0; REST_FRAMES],
            last_end_us: None,
            rest_n: 0,
            pending: (0.0, 0),
            probe: None,
        }
    }

    /// Servo reports since the last resting frame (for the board's tests).
    #[cfg(test)]
    pub(crate) fn pending_reports(&self) -> u16 {
        self.pending.1
    }

    /// The blob's parameters.
    pub fn params(&self) -> &SelfGate {
        &self.p
    }

    /// A probe (the head's own motion) is under way: the board moves the head, not the host.
    pub fn probing(&self) -> bool {
        self.probe.is_some()
    }

    /// A frame while observing (head at rest): kept as the resting face. `pos`: the face
    /// crop's position in the frame, pixels (`FrameHeader::position`); `yaw`: the head's
    /// latest reported yaw, kept for the frame when no servo report came since the last one
    /// (else their mean: [`Gate::on_servo`]); `salient`: the frame's salient pixels (reported
    /// with the decision, for calibration).
    pub fn observe(&mut self, pos: [f32; 2], yaw: f32, salient: u32) {
        let (sum, n) = core::mem::take(&mut self.pending);
        let yaw = if n == 0 { yaw } else { sum / n as f32 };
        self.rest.copy_within(1.., 0);
        self.rest_y.copy_within(1.., 0);
        self.rest[REST_FRAMES - 1] = (pos[0], yaw, salient as f32);
        self.rest_y[REST_FRAMES - 1] = pos[1];
        self.rest_n = (self.rest_n + 1).min(REST_FRAMES as u8);
    }

    /// Forgets the resting frames (the head moved, the model changed).
    pub fn clear(&mut self) {
        self.rest_n = 0;
        self.pending = (0.0, 0);
        self.probe = None;
    }

    fn goal(&self, pr: &Probe) -> [f32; 2] {
        let a = match pr.stage {
            0 => self.p.amplitude,
            1 if pr.via => -self.p.amplitude - VIA_RAD,
            1 => -self.p.amplitude,
            _ => 0.0,
        };
        [pr.rest.1 + a, pr.pitch]
    }

    /// The robot's own latency, microseconds: a pose counts from this long after it settled.
    fn latency_us(&self) -> u64 {
        self.p.latency_ms as u64 * 1000
    }

    /// Probe stages: the two poses, and the return to the rest when the gate has a line test.
    fn stages(&self) -> usize {
        if self.p.line_tol.is_some() { 3 } else { 2 }
    }

    /// A mark was confirmed at `now_us` with the head at `[yaw, pitch]`: the probe starts
    /// (`Wait`: not yet, the head has not rested long enough since the last probe; confirm
    /// again later). The reach `target` waits for the decision.
    pub fn start(&mut self, now_us: u64, frame: u16, head: [f32; 2], target: [f32; 5]) -> Step {
        if self.last_end_us.is_some_and(|t| now_us < t.saturating_add(REST_BEFORE_PROBE_US)) {
            return Step::Wait;
        }
        if self.rest_n == 0 {
            return self.undecided_at(now_us, now_us, frame, GateUndecided::FaceLost);
        }
        let rest = &self.rest[REST_FRAMES - self.rest_n as usize..];
        let n = rest.len() as f32;
        let x = rest.iter().map(|r| r.0).sum::<f32>() / n;
        let sal = rest.iter().map(|r| r.2).sum::<f32>() / n;
        let rest_yaw = rest.iter().map(|r| r.1).sum::<f32>() / n;
        let rest_y = self.rest_y[REST_FRAMES - self.rest_n as usize..].iter().sum::<f32>() / n;
        let (lo, hi) = rest.iter().fold((f32::MAX, f32::MIN), |(l, h), r| (l.min(r.0), h.max(r.0)));
        let pr = Probe {
            started_us: now_us,
            target,
            rest: (x, head[0], sal),
            rest_y,
            rest_yaw,
            rest_spread: hi - lo,
            pitch: head[1],
            stage: 0,
            via: false,
            settled_since: None,
            acc: [Acc::default(); 3],
            last_frame: frame,
        };
        let g = self.goal(&pr);
        self.probe = Some(pr);
        self.rest_n = 0;
        self.pending = (0.0, 0);
        Step::Head(g)
    }

    /// The servos reported the head's yaw (every control period). `Head`: the head passed
    /// the way point below the `-amplitude` pose; now to the pose. Once the head has settled
    /// at a pose and the latency has passed, every report counts towards the pose's yaw: a
    /// reading that wanders by a count or two (a real encoder at rest) averages over the pose's
    /// few hundred milliseconds of reports, not over its handful of frames. Between probes the
    /// reports since the last frame give the next resting frame its yaw ([`Gate::observe`]).
    pub fn on_servo(&mut self, now_us: u64, yaw: f32) -> Step {
        let Some(pr) = self.probe else {
            if self.pending.1 >= REST_REPORTS {
                self.pending = (0.0, 0);
            }
            self.pending = (self.pending.0 + yaw, self.pending.1 + 1);
            return Step::Wait;
        };
        let g = self.goal(&pr);
        if pr.via {
            // Past the pose by more than any friction holds a servo short of a goal.
            if yaw <= g[0] + VIA_RAD / 2.0 {
                if let Some(p) = self.probe.as_mut() {
                    p.via = false;
                }
                return Step::Head(self.goal(&Probe { via: false, ..pr }));
            }
            return Step::Wait;
        }
        let near = (yaw - g[0]).abs() <= SETTLE_SHARE * self.p.amplitude;
        let latency = self.latency_us();
        if let Some(pr) = self.probe.as_mut() {
            pr.settled_since = match (near, pr.settled_since) {
                (true, Some(t)) => Some(t),
                (true, None) => Some(now_us),
                (false, _) => None,
            };
            if pr.counting(now_us, latency) {
                pr.acc[pr.stage as usize].report(yaw);
            }
        }
        Step::Wait
    }

    /// A face frame arrived during the probe; the pipeline found the face it predicts (see
    /// [`Gate::on_probe_frame`]).
    pub fn on_frame(&mut self, now_us: u64, frame: u16, pos: [f32; 2], salient: u32) -> Step {
        self.on_probe_frame(now_us, frame, pos, salient, true)
    }

    /// As [`Gate::on_frame`]; `face`: the pipeline found the face the model predicts at this
    /// head pose (the light fit's verdict). A gate with a return stage passes only when it did
    /// at every probe frame.
    pub fn on_probe_frame(&mut self, now_us: u64, frame: u16, pos: [f32; 2], salient: u32, face: bool) -> Step {
        let latency = self.latency_us();
        let min = self.p.min_frames;
        let stages = self.stages();
        let Some(pr) = self.probe.as_mut() else { return Step::Wait };
        pr.last_frame = frame;
        if !pr.counting(now_us, latency) {
            return Step::Wait;
        }
        let acc = &mut pr.acc[pr.stage as usize];
        acc.push(pos[0], pos[1], salient, face);
        if acc.n < min {
            return Step::Wait;
        }
        if pr.stage as usize + 1 < stages {
            pr.stage += 1;
            // Every pose approached from below (see `VIA_RAD`): the `-amplitude` pose by way
            // of a point past it.
            pr.via = pr.stage == 1;
            pr.settled_since = None;
            let pr = *pr;
            return Step::Head(self.goal(&pr));
        }
        let pr = *pr;
        self.probe = None;
        self.last_end_us = Some(now_us);
        self.decide(now_us, &pr)
    }

    /// The timeout; call every period while probing.
    pub fn poll(&mut self, now_us: u64) -> Step {
        let Some(pr) = self.probe else { return Step::Wait };
        if now_us.saturating_sub(pr.started_us) < self.p.timeout_ms as u64 * 1000 {
            return Step::Wait;
        }
        // Never settled at the pose asked for: the head, not the picture, is at fault.
        let why = if pr.settled_since.is_none() { GateUndecided::HeadStuck } else { GateUndecided::Timeout };
        self.abort(now_us, why)
    }

    /// The probe cannot go on (a watchdog, a bus fault): undecided.
    pub fn abort(&mut self, now_us: u64, why: GateUndecided) -> Step {
        match self.probe.take() {
            Some(pr) => {
                self.last_end_us = Some(now_us);
                self.undecided_at(pr.started_us, now_us, pr.last_frame, why)
            }
            None => Step::Wait,
        }
    }

    fn undecided_at(&self, started_us: u64, now_us: u64, frame: u16, why: GateUndecided) -> Step {
        Step::Done(
            GateReport {
                frame,
                decision: GateDecision::Undecided(why),
                gain_ratio: f32::NAN,
                rest_px: f32::NAN,
                hold_px: f32::NAN,
                level_px: f32::NAN,
                line_px: f32::NAN,
                unlike: 0,
                salient: [f32::NAN; 3],
                frames: [0; 2],
                elapsed_ms: elapsed_ms(started_us, now_us),
            },
            None,
        )
    }

    fn decide(&self, now_us: u64, pr: &Probe) -> Step {
        let ((xp, yp), (xm, ym)) = (pr.acc[0].mean(), pr.acc[1].mean());
        let dy = yp - ym;
        let mut report = GateReport {
            frame: pr.last_frame,
            decision: GateDecision::Undecided(GateUndecided::HeadStuck),
            gain_ratio: f32::NAN,
            rest_px: f32::NAN,
            hold_px: f32::NAN,
            level_px: f32::NAN,
            line_px: f32::NAN,
            unlike: 0,
            salient: [pr.rest.2, pr.acc[0].salient(), pr.acc[1].salient()],
            frames: [pr.acc[0].n, pr.acc[1].n],
            elapsed_ms: elapsed_ms(pr.started_us, now_us),
        };
        // The head must be at the poses it was sent to, as far as the servos can tell, or the
        // probe's geometry is not the commanded one: undecided.
        let a = self.p.amplitude;
        let used = &pr.acc[..self.stages()];
        let back = (self.stages() == 3).then(|| pr.acc[2].mean());
        let there = (yp - (pr.rest.1 + a)).abs() <= POSE_TOL_RAD
            && (ym - (pr.rest.1 - a)).abs() <= POSE_TOL_RAD
            && back.is_none_or(|(_, yb)| (yb - pr.rest.1).abs() <= POSE_TOL_RAD);
        if !(dy.is_finite() && there) {
            return Step::Done(report, None);
        }
        // The commanded span, not the reported one: the servo stops as far from each pose (all
        // approached from below), while its encoder rounds each reported yaw by up to half a
        // step (1 % of the gain over the span), the largest error the gain would have.
        let gain = (xp - xm) / (2.0 * a);
        let ratio = gain / self.p.gain;
        // The poses' midpoint is the resting yaw.
        let line = (xp + xm) / 2.0;
        // The head rested where it came to before the probe, from either side; the poses were
        // approached from below. A servo that friction holds short rested up to twice that off
        // the poses' midpoint (red at one count: 29 own images in 170 refused on the rest), so
        // the line is taken where the encoder says the head rested against the poses (exact
        // servos resting at a goal read the same as their poses' midpoint: no change).
        let drift = pr.rest_yaw - (yp + ym) / 2.0;
        let rest_px = (pr.rest.0 - (line + gain * drift)).abs();
        // Still at rest and at each pose, and level during a yaw probe.
        let hold_px = used.iter().fold(pr.rest_spread, |m, a| m.max(a.x_max - a.x_min));
        let level_px = used.iter().fold(0.0f32, |m, a| m.max((a.y() - pr.rest_y).abs()));
        // Back at the midpoint the servo was sent to: the face on the line, to the match's noise.
        let line_px = back.map_or(f32::NAN, |(xb, _)| (xb - line).abs());
        report.gain_ratio = ratio;
        report.line_px = line_px;
        let unlike = used.iter().fold(0u8, |n, a| n.saturating_add(a.unlike));
        report.unlike = unlike;
        // The mark turns with the face: some of it is salient at a pose, [`MARK_KEPT`] of it at
        // rest at least (without this test a babbling robot whose mark vanished at both poses
        // passed the red gate once in 200).
        let kept = pr.acc[0].salient().max(pr.acc[1].salient());
        let marked = kept > 0.0 && kept >= MARK_KEPT * pr.rest.2;
        report.rest_px = rest_px;
        report.hold_px = hold_px;
        report.level_px = level_px;
        let pass = passes(&self.p, ratio, rest_px, hold_px, level_px, line_px)
            && (self.p.line_tol.is_none() || (unlike == 0 && marked));
        report.decision = if pass { GateDecision::Pass } else { GateDecision::Reject };
        Step::Done(report, pass.then_some(pr.target))
    }
}

/// The gate's decision on a probe's statistics: each within its tolerance (the line's only with
/// a return stage), and, with a joint bound, [`joint`] within it. Written so that a NaN
/// anywhere fails. A gate with a return stage also wants the face and the mark at the poses
/// ([`Gate`] checks those).
pub fn passes(p: &SelfGate, ratio: f32, rest_px: f32, hold_px: f32, level_px: f32, line_px: f32) -> bool {
    (ratio - 1.0).abs() <= p.gain_tol
        && rest_px <= p.rest_tol
        && hold_px <= p.hold_tol
        && level_px <= p.level_tol
        && p.line_tol.is_none_or(|t| line_px <= t)
        && p.joint_tol.is_none_or(|b| joint(p, ratio, rest_px, hold_px, level_px, line_px) <= b)
}

/// The statistics' squared shares of their tolerances, summed (`gain_ratio`'s distance from 1
/// over `gain_tol`, each distance over its own; the line's only with a return stage): how far
/// the probe is from the own image's on all of them at once. A NaN gives NaN, which no bound
/// passes.
pub fn joint(p: &SelfGate, ratio: f32, rest_px: f32, hold_px: f32, level_px: f32, line_px: f32) -> f32 {
    let sq = |v: f32, t: f32| (v / t) * (v / t);
    let line = p.line_tol.map_or(0.0, |t| sq(line_px, t));
    sq(ratio - 1.0, p.gain_tol) + sq(rest_px, p.rest_tol) + sq(hold_px, p.hold_tol) + sq(level_px, p.level_tol) + line
}

/// Least rest of the head between two probes: longer than the longest video delay the gate
/// must refuse (2 s), so that a delayed picture shows the head still when the next probe starts.
pub const REST_BEFORE_PROBE_US: u64 = 2_500_000;

/// The share of the resting mark's salient pixels the mark keeps at one pose at least (a gate
/// with a return stage). A babbling robot whose mark kept 2 of its 356 pixels at one pose
/// (0.006) passed the red gate once in 186 probes on the Dynamixel bus (seed 9001); the own
/// image kept a quarter or more in 3903 passes over lights and servos, and an older red mirror
/// trial 7 of about 300 at one pose (0.023).
pub const MARK_KEPT: f32 = 0.015;

/// How far below the `-amplitude` pose the head turns before it goes to the pose, radians
/// (about ten counts of a 12-bit encoder). Every probe pose is then approached from below, as a
/// machine tool approaches its positions from one side against backlash: a servo whose holding
/// loop has no integral term stops short of a goal under static friction (or off it under a
/// load) on the side it came from, by as much at each pose, so the span between the poses and
/// their midpoint are the commanded ones. Approached from both sides, a servo stopping half a
/// count short shrank the span by a count in 91 (1.1 % of the gain): a robot of the same look
/// holding still, whose face moves with the camera's turn alone (a gain about 3 % off the own
/// image's), passed the red gate in 85 of 186 probes (seed 9001), and at one count short the
/// gate refused every own image.
pub const VIA_RAD: f32 = 0.015;

/// At the decision, the mean reported yaw at each pose must be this close to the pose
/// (radians; about five steps of a 12-bit servo encoder: a servo that friction stops three
/// counts short reads up to three and a half off, and the poses, all approached from below,
/// keep the commanded span; at three steps every such probe was undecided).
pub const POSE_TOL_RAD: f32 = 0.008;

/// The head is at a probe pose when its reported yaw is this share of the amplitude from it.
pub const SETTLE_SHARE: f32 = 0.15;

fn elapsed_ms(from_us: u64, to_us: u64) -> u16 {
    (to_us.saturating_sub(from_us) / 1000).min(u16::MAX as u64) as u16
}

#[cfg(test)]
pub(crate) mod tests;
