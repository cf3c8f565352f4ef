//! The head's settling: when a head pose the host asked for has settled, and which head pose the
//! pipeline and the self gate are given while the servos hold still.

use crate::motion::Motion;

/// The head holds still while both head servos' readings stay within this of where they were
/// (two counts of a 12-bit encoder): a reading may flicker by a count or two at rest.
pub const SETTLE_RAD: f32 = 0.0031;
/// How far from the asked pose a head servo may hold (eight counts of a 12-bit encoder, 0.7
/// degrees): a servo without an integral term holds off its goal by as much as its load
/// takes back (gravity on the pitch), and sending it the goal again keeps it there.
pub const HOLD_RAD: f32 = 0.0123;
/// A head move has settled when both head servos report within [`HOLD_RAD`] of the asked pose
/// and within [`STILL_RAD`] of where they were at the first of this many control periods in a
/// row.
pub const SETTLE_PERIODS: u8 = 4;
/// One count of a 12-bit encoder: a servo still approaching where it holds moves by more than
/// this over [`SETTLE_PERIODS`] periods until it is within about two counts of it (first order,
/// a 30 ms time constant), so the angles a settled move reports are where the head holds.
pub const STILL_RAD: f32 = 0.0016;
/// How long past the move's planned duration the head may take to settle.
pub const SETTLE_MARGIN_US: u64 = 1_000_000;

/// Both head angles (yaw, pitch) within `band` of the other pose's (false with a NaN).
fn within(band: f32, a: [f32; 2], b: [f32; 2]) -> bool {
    (a[0] - b[0]).abs() <= band && (a[1] - b[1]).abs() <= band
}

/// A head pose asked for and not yet answered.
#[derive(Clone, Copy, Debug, PartialEq)]
struct HeadMove {
    goal: [f32; 2],
    since_us: u64,
    deadline_us: u64,
    settled_periods: u8,
    /// The readings the periods counted in `settled_periods` stayed near.
    still_at: [f32; 2],
}

/// What one control period made of the head move in progress.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Settle {
    /// No move is waited on.
    Idle,
    /// The move goes on.
    Moving,
    /// The servos hold still at the asked pose.
    Settled,
    /// Out of time, or a reach took the head elsewhere, after this many milliseconds.
    NotSettled(u32),
}

/// The head move the host asked for and waits on.
pub(super) struct Head {
    pending: Option<HeadMove>,
}

/// The head pose the pipeline was last given (NaN: none yet); see [`Steady::pose`].
pub(super) struct Steady([f32; 2]);

impl Steady {
    pub(super) const fn new() -> Self {
        Steady([f32::NAN; 2])
    }

    /// The head pose for the pipeline: the one it was last given while both head servos report
    /// within [`SETTLE_RAD`] (two counts) of it, else `head`, which becomes that pose. A servo
    /// holding still may read the counts around its position by turns; each changed reading
    /// would make the prediction again (the decoder, about 48 instructions a pixel), and the
    /// room learns from no frame that did.
    pub(super) fn pose(&mut self, head: [f32; 2]) -> [f32; 2] {
        if !within(SETTLE_RAD, head, self.0) {
            self.0 = head;
        }
        self.0
    }
}

impl Head {
    pub(super) const fn new() -> Self {
        Head { pending: None }
    }

    /// A move to `goal` began at `now_us`, planned to take `planned_us`.
    pub(super) fn start(&mut self, goal: [f32; 2], now_us: u64, planned_us: u64) {
        self.pending = Some(HeadMove {
            goal,
            since_us: now_us,
            deadline_us: now_us + planned_us + SETTLE_MARGIN_US,
            settled_periods: 0,
            still_at: goal,
        });
    }

    /// A move the host asked for is in progress.
    pub(super) fn moving(&self) -> bool {
        self.pending.is_some()
    }

    /// After each control period: `measured` are the servos' readings in the reach joints'
    /// order (the head's first), `motion` what takes the head where it goes.
    pub(super) fn check(&mut self, now_us: u64, measured: &[Option<f32>; 5], motion: &Motion) -> Settle {
        let Some(mut m) = self.pending else { return Settle::Idle };
        let commanded = motion.commanded();
        let reached = commanded.is_some_and(|c| c[0] == m.goal[0] && c[1] == m.goal[1]);
        m.settled_periods = match (measured[0], measured[1]) {
            (Some(y), Some(p)) if reached && within(HOLD_RAD, [y, p], m.goal) => {
                if m.settled_periods > 0 && within(STILL_RAD, [y, p], m.still_at) {
                    m.settled_periods.saturating_add(1)
                } else {
                    m.still_at = [y, p];
                    1
                }
            }
            _ => 0,
        };
        if m.settled_periods >= SETTLE_PERIODS {
            self.pending = None;
            Settle::Settled
        } else if now_us >= m.deadline_us || motion.head_goal() != m.goal {
            self.pending = None;
            Settle::NotSettled((now_us.saturating_sub(m.since_us) / 1000) as u32)
        } else {
            self.pending = Some(m);
            Settle::Moving
        }
    }
}

/// Where the head holds, for the self gate's probe: the motion's head goal `goal` while both
/// head servos report within [`HOLD_RAD`] of it, else `reading`. A servo holding still holds
/// where it holds for that goal, while its reading may be a count or two off (encoder noise, a
/// holding loop's dither) or several (a pitch servo sagging under the head); a probe centred on
/// the reading would move the head by those counts, in pitch too, and the gate would see its
/// own image move (the level test).
pub(super) fn held(reading: [f32; 2], goal: [f32; 2]) -> [f32; 2] {
    if within(HOLD_RAD, reading, goal) {
        goal
    } else {
        reading
    }
}
