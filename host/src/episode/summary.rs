//! What trials report: each trial's outcome, the self gate's decisions as the PC saw them, and
//! the summary of a run.
use super::config::{Backend, ServoBus};
use msr_shared::deliver::LinkStats;
use msr_shared::msg::{GateDecision, GateReport, Status};
use msr_sim::Robot;
use serde::{Deserialize, Serialize};

/// One decision of the board's self gate, as the PC saw it.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct GateRecord {
    /// Simulated time of the report, ms.
    pub at_ms: f64,
    /// `pass`, `reject` or `undecided: <why>`.
    pub decision: String,
    /// `null` when undecided before both probe poses (NaN on the wire).
    pub gain_ratio: Option<f32>,
    /// Distance of the resting face from the probe's line, pixels (`null` as above).
    pub rest_px: Option<f32>,
    /// Largest range of the face's x while the head held (rest, each pose), pixels.
    #[serde(default)]
    pub hold_px: Option<f32>,
    /// Largest vertical move of the face at a pose from its rest, pixels.
    #[serde(default)]
    pub level_px: Option<f32>,
    /// With a return stage: the face back at the resting yaw, its distance from the probe's
    /// line, pixels.
    #[serde(default)]
    pub line_px: Option<f32>,
    /// Probe frames that did not show the face the model predicts there (return stage only).
    #[serde(default)]
    pub unlike: u8,
    /// Mean salient pixels at rest and at the two probe poses.
    pub salient: [Option<f32>; 3],
    /// Frames used at the two probe poses.
    pub frames: [u8; 2],
    /// From the mark's confirmation to the decision, milliseconds of board time.
    pub elapsed_ms: u16,
    /// The statistics' squared shares of the model gate's tolerances, summed
    /// (`msr_firmware::self_gate::joint`; the gate passes at most its `joint_tol`): how near the
    /// tolerances the probe came all at once. `null` when undecided or not worked out
    /// ([`add_gate_joints`]).
    #[serde(default)]
    pub joint: Option<f32>,
}

impl GateRecord {
    /// The record of the board's report `g`, received at simulated time `at_us` (microseconds);
    /// NaN statistics become `None`.
    pub fn of(at_us: u64, g: &GateReport) -> GateRecord {
        let finite = |v: f32| v.is_finite().then_some(v);
        GateRecord {
            at_ms: at_us as f64 / 1000.0,
            decision: match g.decision {
                GateDecision::Pass => "pass".into(),
                GateDecision::Reject => "reject".into(),
                GateDecision::Undecided(w) => format!("undecided: {w:?}"),
            },
            gain_ratio: finite(g.gain_ratio),
            rest_px: finite(g.rest_px),
            hold_px: finite(g.hold_px),
            level_px: finite(g.level_px),
            line_px: finite(g.line_px),
            unlike: g.unlike,
            salient: g.salient.map(finite),
            frames: g.frames,
            elapsed_ms: g.elapsed_ms,
            joint: None,
        }
    }

    /// [`GateRecord::joint`] under `gate`, the gate that decided (the report does not carry it).
    pub fn joint_under(&self, gate: &msr_shared::blob::SelfGate) -> Option<f32> {
        let line = match gate.line_tol {
            Some(_) => self.line_px?,
            None => 0.0,
        };
        let j = msr_firmware::self_gate::joint(gate, self.gain_ratio?, self.rest_px?, self.hold_px?, self.level_px?, line);
        j.is_finite().then_some(j)
    }
}

/// Fills every gate decision's [`GateRecord::joint`] under `gate`, the model's.
pub fn add_gate_joints(trials: &mut [Trial], gate: &msr_shared::blob::SelfGate) {
    for r in trials.iter_mut().flat_map(|t| t.gate.iter_mut()) {
        r.joint = r.joint_under(gate);
    }
}

/// One trial's outcome (`Default`: nothing happened yet).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Trial {
    /// The trial's place in its run, from 0 (its seed comes from it).
    pub index: usize,
    /// The scene (`mirror`, `other`, `delayed`).
    pub scene: String,
    /// Delayed scene: the video delay.
    pub delay_ms: Option<f64>,
    /// Other scene: whether the other robot babbled its head (else it held still).
    pub other_babbles: Option<bool>,
    /// The self gate's decisions, in order (empty without a gate in the model).
    pub gate: Vec<GateRecord>,
    /// The mark (kind, colour) when one was put on the face.
    pub mark: Option<String>,
    /// The trial was drawn to get a mark but ended (a false reach) before the mark appeared: it
    /// counts neither as a marked trial nor as one without a mark.
    pub ended_before_mark: bool,
    /// The mark's centre in the frame at head (0, 0), pixels.
    pub mark_pixel: Option<[f64; 2]>,
    /// A reach started (the board confirmed a detection).
    pub reached: bool,
    /// A reach while no mark was on the face.
    pub false_reach: bool,
    /// The held reach touched the mark (every judged sample within the touch radius of it).
    pub touched: bool,
    /// Worst fingertip-to-mark distance while held (marked trials with a held reach).
    pub touch_error_mm: Option<f64>,
    /// How the sim's arm differed from its drawing (absent: the drawing itself).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arm_error: Option<msr_sim::kin::ArmError>,
    /// Simulated time from the mark appearing to the reach starting.
    pub latency_ms: Option<f64>,
    /// The reach target the board streamed, when it reached.
    pub reach_target: Option<[f32; 5]>,
    /// Why a marked trial failed, for finding the stage at fault.
    pub failure: Option<String>,
    /// Camera frames the PC shot and sent to the board.
    pub frames_sent: u32,
    /// Board answers with a blob (a candidate mark), confirmed or not.
    pub detections: u32,
    /// Servo targets the emulated servos refused: outside a joint's limits, not finite, or for
    /// a joint with no limits.
    pub limit_violations: u32,
    /// Frames that failed their CRC, at every end of both links (PC, board, servos).
    pub crc_errors: u32,
    /// Damaged frames dropped and resynchronised past (CRC, COBS, size, content), at every end
    /// of both links.
    pub resyncs: u32,
    /// Trips of the board's face and servo watchdogs.
    pub watchdog_trips: u32,
    /// The PC's face-frame delivery: frames delivered and superseded, bytes, chunks resent.
    pub link: LinkStats,
    /// Simulated time the trial ran, seconds.
    pub sim_s: f64,
    /// Wall-clock time the trial took, seconds.
    pub wall_s: f64,
    /// What the board sent on the servo bus, when
    /// [`EpisodeConfig::log_bus`](super::EpisodeConfig::log_bus).
    #[serde(skip)]
    pub bus_bytes: Vec<u8>,
    /// The trial as ROS 2 messages, when [`EpisodeConfig::mcap`](super::EpisodeConfig::mcap).
    #[serde(skip)]
    pub log: Option<crate::rosbag::session::SessionLog>,
    /// Frames the board answered with no detection because the photometric fit refused them
    /// as `NoFace` (the crop does not follow the predicted face).
    #[serde(default)]
    pub no_face_frames: u32,
    /// Frames the photometric fit refused as `SceneChanged` (light outside what it explains).
    #[serde(default)]
    pub scene_changed_frames: u32,
}

/// The summary `msr mirror-test --json` prints, exactly these keys.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Summary {
    /// What ran the firmware: `inproc` or `qemu`.
    pub backend: String,
    /// The robot drawn: `red` or `skin`.
    pub robot: String,
    /// The servo bus's protocol: `framed` or `dynamixel`.
    pub servo_bus: String,
    /// The scene of the trials.
    pub scene: String,
    /// Trials run.
    pub trials: usize,
    /// Trials in which a reach started, marked or not.
    pub reaches: usize,
    /// The self gate's pass decisions over all trials.
    pub gate_passes: usize,
    /// The self gate's reject decisions over all trials.
    pub gate_rejects: usize,
    /// The self gate's undecided reports over all trials (a timeout, a face lost...).
    pub gate_undecided: usize,
    /// Trials in which a mark appeared on the face.
    pub marked_trials: usize,
    /// Marked trials whose held reach touched the mark.
    pub touched: usize,
    /// Touched / marked trials; `null` when no trial had a mark.
    pub touch_rate: Option<f64>,
    /// Trials that never had a mark, not counting those drawn to get one that ended before it
    /// appeared.
    pub no_mark_trials: usize,
    /// Trials drawn to get a mark that ended (a false reach) before it appeared.
    pub ended_before_mark: usize,
    /// Reaches while no mark was on the face, over all trials.
    pub false_reaches: usize,
    /// Median of the marked trials' worst fingertip-to-mark distance while held, millimetres;
    /// `null` without a held reach.
    pub median_touch_error_mm: Option<f64>,
    /// Median simulated time from the mark appearing to the reach starting, over the marked
    /// trials that reached, milliseconds.
    pub latency_ms_median: Option<f64>,
    /// Servo targets refused by the emulated servos, over all trials ([`Trial::limit_violations`]).
    pub limit_violations: u64,
    /// Frames that failed their CRC at every end of both links, over all trials.
    pub crc_errors: u64,
    /// Damaged frames dropped and resynchronised past at every end of both links, over all
    /// trials.
    pub resyncs: u64,
    /// Trips of the board's face and servo watchdogs, over all trials.
    pub watchdog_trips: u64,
    /// Face bytes the board took whole per simulated second, over all trials.
    pub goodput_bytes_per_s: f64,
    /// Face chunks sent again (selective repeat).
    pub retransmissions: u64,
    /// Face frames given up unfinished for a newer one.
    pub frames_superseded: u64,
    /// Frames refused by the photometric fit as `NoFace`, over all trials.
    #[serde(default)]
    pub no_face_frames: u64,
    /// Frames refused by the photometric fit as `SceneChanged`, over all trials.
    #[serde(default)]
    pub scene_changed_frames: u64,
    /// Robot time of all trials, seconds.
    #[serde(default)]
    pub sim_s: f64,
    /// What the board had learnt of the room at the end of a run on one board (`--one-board`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub room: Option<msr_shared::msg::RoomReport>,
    /// What the live server served (`--live`): clients, messages, and those dropped for
    /// clients that read too slowly.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub live: Option<crate::live::LiveStats>,
}

impl std::fmt::Display for Summary {
    /// One line: the counts, rates and medians, the face link, the room and the live view.
    fn fmt(&self, out: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = self;
        let f = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.1}"));
        let early = if s.ended_before_mark > 0 {
            format!(", {} ended before the mark appeared", s.ended_before_mark)
        } else {
            String::new()
        };
        let line = format!(
            "{} {} ({} servo bus, scene {}): {} trials, {} reaches, self gate {} pass / {} reject / {} undecided, \
             touched {}/{} marked ({} %), false reaches {} ({} trials without a mark{early}), \
             median touch error {} mm, median latency {} ms, limit violations {}, CRC errors {}, resyncs {}, \
             watchdog trips {}; face link: goodput {:.0} B/s, {} chunks sent again, {} frames superseded",
            s.backend,
            s.robot,
            s.servo_bus,
            s.scene,
            s.trials,
            s.reaches,
            s.gate_passes,
            s.gate_rejects,
            s.gate_undecided,
            s.touched,
            s.marked_trials,
            f(s.touch_rate.map(|r| 100.0 * r)),
            s.false_reaches,
            s.no_mark_trials,
            f(s.median_touch_error_mm),
            f(s.latency_ms_median),
            s.limit_violations,
            s.crc_errors,
            s.resyncs,
            s.watchdog_trips,
            s.goodput_bytes_per_s,
            s.retransmissions,
            s.frames_superseded
        ) + &s.room.map_or(String::new(), |r| {
            format!("; {:.1} min of robot time on one board, {}", s.sim_s / 60.0, crate::describe::describe_room(&r))
        }) + &s.live.map_or(String::new(), |l| format!("; {l}"));
        out.write_str(&line)
    }
}

/// The median of `v` (the mean of the middle two for an even count); `None` when empty.
pub fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    let n = v.len();
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    })
}

fn gate_count(trials: &[Trial], f: fn(&str) -> bool) -> usize {
    trials.iter().flat_map(|t| &t.gate).filter(|g| f(&g.decision)).count()
}

/// The summary of `trials`, run with `backend` on `robot` over `bus`; `room` and `live` are
/// left for the caller to fill.
pub fn summarise(backend: Backend, robot: Robot, bus: ServoBus, trials: &[Trial]) -> Summary {
    let marked: Vec<&Trial> = trials.iter().filter(|t| t.mark.is_some()).collect();
    let touched = marked.iter().filter(|t| t.touched).count();
    let sum = |f: fn(&Trial) -> u32| trials.iter().map(|t| f(t) as u64).sum::<u64>();
    Summary {
        backend: backend.name().into(),
        robot: robot.name().into(),
        servo_bus: bus.name().into(),
        scene: trials.first().map_or("mirror".into(), |t| t.scene.clone()),
        trials: trials.len(),
        reaches: trials.iter().filter(|t| t.reached).count(),
        gate_passes: gate_count(trials, |d| d == "pass"),
        gate_rejects: gate_count(trials, |d| d == "reject"),
        gate_undecided: gate_count(trials, |d| d.starts_with("undecided")),
        marked_trials: marked.len(),
        touched,
        touch_rate: (!marked.is_empty()).then(|| touched as f64 / marked.len() as f64),
        no_mark_trials: trials
            .iter()
            .filter(|t| t.mark.is_none() && !t.ended_before_mark)
            .count(),
        ended_before_mark: trials.iter().filter(|t| t.ended_before_mark).count(),
        false_reaches: trials.iter().filter(|t| t.false_reach).count(),
        median_touch_error_mm: median(marked.iter().filter_map(|t| t.touch_error_mm).collect()),
        latency_ms_median: median(marked.iter().filter_map(|t| t.latency_ms).collect()),
        limit_violations: sum(|t| t.limit_violations),
        crc_errors: sum(|t| t.crc_errors),
        resyncs: sum(|t| t.resyncs),
        watchdog_trips: sum(|t| t.watchdog_trips),
        goodput_bytes_per_s: {
            let secs: f64 = trials.iter().map(|t| t.sim_s).sum();
            let bytes: u64 = trials.iter().map(|t| t.link.face_bytes).sum();
            if secs > 0.0 { bytes as f64 / secs } else { 0.0 }
        },
        retransmissions: trials.iter().map(|t| t.link.chunks_resent).sum(),
        frames_superseded: trials.iter().map(|t| t.link.superseded as u64).sum(),
        no_face_frames: sum(|t| t.no_face_frames),
        scene_changed_frames: sum(|t| t.scene_changed_frames),
        sim_s: trials.iter().map(|t| t.sim_s).sum(),
        room: None,
        live: None,
    }
}

/// A trial's end: the board's last status into its counters and, at the trial's end, its log.
pub fn end_with_status(trial: &mut Trial, s: &Status) {
    add_board_counters(trial, s);
    if let Some(l) = &mut trial.log {
        l.status((trial.sim_s * 1e6) as u64, s);
    }
}

/// Adds the board's link counters and watchdog trips to a trial's.
pub fn add_board_counters(trial: &mut Trial, s: &Status) {
    trial.crc_errors += s.host_link.crc_errors + s.servo_link.crc_errors;
    trial.resyncs += s.host_link.resyncs() + s.servo_link.resyncs();
    trial.watchdog_trips += s.face_watchdog_trips + s.servo_watchdog_trips;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_gate_records_joint_is_its_statistics_over_the_tolerances() {
        let gate = msr_shared::blob::SelfGate {
            amplitude: 0.07,
            gain: 296.0,
            gain_tol: 0.02,
            rest_tol: 0.5,
            hold_tol: 0.4,
            level_tol: 0.2,
            line_tol: Some(0.25),
            joint_tol: Some(0.875),
            latency_ms: 250,
            timeout_ms: 2500,
            min_frames: 2,
        };
        let report = GateReport {
            frame: 9,
            decision: GateDecision::Reject,
            gain_ratio: 1.01,
            rest_px: 0.25,
            hold_px: 0.2,
            level_px: 0.1,
            line_px: 0.125,
            unlike: 0,
            salient: [50.0, 60.0, 70.0],
            frames: [2, 2],
            elapsed_ms: 1600,
        };
        let mut trial = Trial::default();
        trial.gate.push(GateRecord::of(2_000_000, &report));
        // Undecided: no statistics, no joint.
        trial.gate.push(GateRecord::of(5_000_000, &GateReport { decision: GateDecision::Undecided(msr_shared::msg::GateUndecided::Timeout), gain_ratio: f32::NAN, ..report }));
        assert_eq!(trial.gate[0].joint, None);
        add_gate_joints(std::slice::from_mut(&mut trial), &gate);
        // Each statistic half its tolerance: 5 x 0.25.
        let j = trial.gate[0].joint.unwrap();
        assert!((j - 1.25).abs() < 1e-3, "{j}");
        assert_eq!(trial.gate[1].joint, None);
        // A two-stage gate leaves the line out.
        let two = msr_shared::blob::SelfGate { line_tol: None, joint_tol: None, ..gate };
        assert!((trial.gate[0].joint_under(&two).unwrap() - 1.0).abs() < 1e-3);
        let json = serde_json::to_value(&trial.gate[0]).unwrap();
        assert!((json["joint"].as_f64().unwrap() - 1.25).abs() < 1e-3);
    }
}
