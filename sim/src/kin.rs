//! Nao kinematics: forward kinematics of the head, the top camera and the left arm, inverse
//! kinematics for touching a point on the face, and the touch judge.
//!
//! Frames follow Nao's convention (x forward, y left, z up, metres, radians); joint origins are
//! the URDF numbers of the mission document. Positive HeadPitch looks down, positive
//! LShoulderPitch lowers the arm, positive LShoulderRoll moves it outwards.
//!
//! Joints that the reach does not drive sit at [`ARM_FIXED`]: LElbowYaw = -0.3 tilts the elbow so
//! that LElbowRoll bends the forearm inwards and a little upwards, in front of the face; of the
//! values tried (0 to -pi/2) it is the one that reaches the whole mark area (`body::FACE_Y`,
//! `body::FACE_Z`) within the limits. LWristYaw = 0. The end effector is the URDF hand point (`LWristYaw` + (57.75, 0, -12.31) mm),
//! called the fingertip here.
mod arm_error;
pub use self::arm_error::{ArmError, ArmErrorBound};
use msr_shared::joints::{Joint, HOME_POSTURE};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

/// The head shell in the head frame: centre and semi-axes (metres); the renderer draws it and
/// the reach keeps the arm out of it.
pub const HEAD_ELLIPSOID: ([f64; 3], [f64; 3]) = ([0.0, 0.0, 0.060], [0.062, 0.066, 0.068]);

/// Torso to HeadYaw.
pub const NECK_OFFSET_Z: f64 = 0.1265;
/// Head (HeadPitch frame) to the top camera.
pub const CAMERA_OFFSET: [f64; 3] = [0.05871, 0.0, 0.06364];
/// Torso to LShoulderPitch.
pub const SHOULDER_OFFSET: [f64; 3] = [0.0, 0.098, 0.100];
/// LShoulderRoll to LElbowYaw.
pub const UPPER_ARM: [f64; 3] = [0.105, 0.015, 0.0];
/// LElbowRoll to LWristYaw.
pub const LOWER_ARM_X: f64 = 0.05595;
/// LWristYaw to the hand point.
pub const HAND_OFFSET: [f64; 3] = [0.05775, 0.0, -0.01231];

/// LElbowYaw and LWristYaw, fixed during a reach (see the module note).
pub const ARM_FIXED: [f64; 2] = [-0.3, 0.0];

/// A touch: fingertip within this distance of the mark's point.
pub const TOUCH_RADIUS_M: f64 = 0.020;

/// The five reach joints: HeadYaw, HeadPitch, LShoulderPitch, LShoulderRoll, LElbowRoll.
pub type Reach = [f64; 5];

/// The published home posture as f64.
pub fn home() -> Reach {
    HOME_POSTURE.map(f64::from)
}

/// Limits of the five reach joints, [min, max], kept 1e-5 rad inside the table so that a
/// posture stays inside after a round trip through f32 or decimal text.
pub fn reach_limits() -> [[f64; 2]; 5] {
    msr_shared::joints::REACH_JOINTS.map(|j| {
        let l = j.limits().expect("reach joints have limits");
        [l.min as f64 + 1e-5, l.max as f64 - 1e-5]
    })
}

fn rot_x(a: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&Vector3::x_axis(), a)
}
fn rot_y(a: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&Vector3::y_axis(), a)
}
fn rot_z(a: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), a)
}
fn tr(v: [f64; 3]) -> Translation3<f64> {
    Translation3::new(v[0], v[1], v[2])
}
fn iso(t: [f64; 3], r: UnitQuaternion<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(tr(t), r)
}

/// Torso <- head (HeadPitch frame).
pub fn head_pose(yaw: f64, pitch: f64) -> Isometry3<f64> {
    iso([0.0, 0.0, NECK_OFFSET_Z], rot_z(yaw)) * iso([0.0; 3], rot_y(pitch))
}

/// Torso <- top camera (x along the optical axis, y left, z up).
pub fn camera_pose(yaw: f64, pitch: f64) -> Isometry3<f64> {
    head_pose(yaw, pitch) * iso(CAMERA_OFFSET, UnitQuaternion::identity())
}

/// Left arm angles in chain order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LeftArm {
    /// LShoulderPitch, radians.
    pub shoulder_pitch: f64,
    /// LShoulderRoll, radians.
    pub shoulder_roll: f64,
    /// LElbowYaw, radians.
    pub elbow_yaw: f64,
    /// LElbowRoll, radians.
    pub elbow_roll: f64,
    /// LWristYaw, radians.
    pub wrist_yaw: f64,
}

impl LeftArm {
    /// The arm of a reach vector, with the fixed joints at [`ARM_FIXED`].
    pub fn from_reach(q: &Reach) -> LeftArm {
        LeftArm {
            shoulder_pitch: q[2],
            shoulder_roll: q[3],
            elbow_yaw: ARM_FIXED[0],
            elbow_roll: q[4],
            wrist_yaw: ARM_FIXED[1],
        }
    }

    /// The home arm.
    pub fn home() -> LeftArm {
        LeftArm::from_reach(&home())
    }

    /// The right arm drawn as the mirror image of this one (y negated, rolls and yaws flipped).
    pub fn mirrored(&self) -> LeftArm {
        LeftArm {
            shoulder_pitch: self.shoulder_pitch,
            shoulder_roll: -self.shoulder_roll,
            elbow_yaw: -self.elbow_yaw,
            elbow_roll: -self.elbow_roll,
            wrist_yaw: -self.wrist_yaw,
        }
    }
}

/// Points along the left arm in the torso frame.
#[derive(Clone, Copy, Debug)]
pub struct ArmPoints {
    /// The shoulder joint.
    pub shoulder: Point3<f64>,
    /// The elbow joint.
    pub elbow: Point3<f64>,
    /// The wrist joint.
    pub wrist: Point3<f64>,
    /// The fingertip (the URDF hand point).
    pub fingertip: Point3<f64>,
}

/// Forward kinematics of the left arm. `side` is +1 for the left arm, -1 for a right arm given as
/// [`LeftArm::mirrored`] angles (its offsets have y negated).
pub fn arm_points(a: &LeftArm, side: f64) -> ArmPoints {
    arm_points_of(a, side, &ArmError::EXACT)
}

/// [`arm_points`] of an arm that is not its drawing: each joint at its angle plus its zero
/// offset, each link scaled.
pub fn arm_points_of(a: &LeftArm, side: f64, e: &ArmError) -> ArmPoints {
    let s = |v: [f64; 3], k: f64| [k * v[0], k * side * v[1], k * v[2]];
    let z = e.zero_rad;
    let shoulder = iso(s(SHOULDER_OFFSET, 1.0), rot_y(a.shoulder_pitch + z[0]) * rot_z(a.shoulder_roll + z[1]));
    let elbow = shoulder * iso(s(UPPER_ARM, e.length[0]), rot_x(a.elbow_yaw + z[2]) * rot_z(a.elbow_roll + z[3]));
    let wrist = elbow * iso([e.length[1] * LOWER_ARM_X, 0.0, 0.0], rot_x(a.wrist_yaw + z[4]));
    let hand = wrist * Point3::from(Vector3::from(s(HAND_OFFSET, e.length[2])));
    ArmPoints {
        shoulder: shoulder * Point3::origin(),
        elbow: elbow * Point3::origin(),
        wrist: wrist * Point3::origin(),
        fingertip: hand,
    }
}

/// The left fingertip in the torso frame.
pub fn fingertip(q: &Reach) -> Point3<f64> {
    fingertip_of(q, &ArmError::EXACT)
}

/// The left fingertip of an arm that is not its drawing.
pub fn fingertip_of(q: &Reach, e: &ArmError) -> Point3<f64> {
    arm_points_of(&LeftArm::from_reach(q), 1.0, e).fingertip
}

/// A point given in the head frame, in the torso frame at these head angles.
pub fn head_to_torso(p_head: &Point3<f64>, yaw: f64, pitch: f64) -> Point3<f64> {
    head_pose(yaw, pitch) * p_head
}

/// Fingertip-to-mark distance for a posture; the mark moves with the head.
pub fn touch_distance(q: &Reach, mark_head: &Point3<f64>) -> f64 {
    touch_distance_of(q, mark_head, &ArmError::EXACT)
}

/// [`touch_distance`] for an arm that is not its drawing.
pub fn touch_distance_of(q: &Reach, mark_head: &Point3<f64>, e: &ArmError) -> f64 {
    (fingertip_of(q, e) - head_to_torso(mark_head, q[0], q[1])).norm()
}

/// Judges a reach from the measured joint angles of the five reach joints, sampled while the
/// reach is held: a touch needs every sample within [`TOUCH_RADIUS_M`]. Returns the worst distance
/// too. No samples is no touch.
/// A sample that is not finite (a NaN angle) is no touch, and the worst distance is NaN.
pub fn judge_touch(held: &[Reach], mark_head: &Point3<f64>) -> (bool, f64) {
    judge_touch_of(held, mark_head, &ArmError::EXACT, TOUCH_RADIUS_M)
}

/// [`judge_touch`] for an arm that is not its drawing, with a touch radius of `radius_m` metres.
pub fn judge_touch_of(held: &[Reach], mark_head: &Point3<f64>, e: &ArmError, radius_m: f64) -> (bool, f64) {
    let mut worst = f64::NEG_INFINITY;
    for q in held {
        let d = touch_distance_of(q, mark_head, e);
        if !d.is_finite() {
            return (false, f64::NAN);
        }
        worst = worst.max(d);
    }
    if held.is_empty() {
        return (false, f64::NAN);
    }
    (worst <= radius_m, worst)
}

/// What of the left arm meets the head (the head's shell, [`HEAD_ELLIPSOID`]), as the robot feels
/// it: the skin robot through its head's taxels, a servo through its load.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Contact {
    /// The fingertip is on or inside the shell.
    Fingertip,
    /// The wrist or the elbow is within [`ARM_CONTACT_MARGIN_M`] of the shell (the forearm's
    /// thickness), before the fingertip.
    Arm,
}

/// How close the wrist or the elbow comes to the head's shell before the forearm touches it.
pub const ARM_CONTACT_MARGIN_M: f64 = 0.010;

/// Where the torso-frame point `p` lies against the head's shell grown by `grow` metres, at the
/// head angles of `q`: below 1 inside, 1 on it, above 1 outside (the ellipsoid's quadratic form).
fn head_shell_level(q: &Reach, p: &Point3<f64>, grow: f64) -> f64 {
    let h = head_pose(q[0], q[1]).inverse() * p;
    let (c, r) = HEAD_ELLIPSOID;
    ((h.x - c[0]) / (r[0] + grow)).powi(2) + ((h.y - c[1]) / (r[1] + grow)).powi(2) + ((h.z - c[2]) / (r[2] + grow)).powi(2)
}

/// Whether the arm of `q` (an arm that is not its drawing: `e`) meets the head, and with what.
pub fn contact_of(q: &Reach, e: &ArmError) -> Option<Contact> {
    let pts = arm_points_of(&LeftArm::from_reach(q), 1.0, e);
    let inside = |p: &Point3<f64>, grow: f64| head_shell_level(q, p, grow) <= 1.0;
    if inside(&pts.fingertip, 0.0) {
        Some(Contact::Fingertip)
    } else if inside(&pts.wrist, ARM_CONTACT_MARGIN_M) || inside(&pts.elbow, ARM_CONTACT_MARGIN_M) {
        Some(Contact::Arm)
    } else {
        None
    }
}

/// Why the IK found no posture.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum IkError {
    #[error("mark point is not finite")]
    /// The point has a coordinate that is not finite.
    NotFinite,
    #[error("no posture within the joint limits puts the fingertip on the point (best {best_mm:.1} mm)")]
    /// No posture reaches the point; `best_mm` is the closest miss.
    Unreachable {
        /// The closest the fingertip came, millimetres.
        best_mm: f64,
    },
}

/// Head ellipsoid the arm must stay out of during a reach (head frame; centre, semi-axes).
/// [`HEAD_ELLIPSOID`], slightly grown.
fn arm_clear_of_head(q: &Reach, margin: f64) -> f64 {
    let pts = arm_points(&LeftArm::from_reach(q), 1.0);
    let mut pen = 0.0;
    for p in [pts.elbow, pts.wrist] {
        let d = head_shell_level(q, &p, margin);
        if d < 1.0 {
            pen += 1.0 - d;
        }
    }
    pen
}

/// Residuals the IK minimises: the position error (metres, weight 1), a gentle pull towards
/// a neutral head, and a penalty for the elbow or wrist inside the head.
fn residuals(q: &Reach, mark_head: &Point3<f64>) -> [f64; 6] {
    let e = fingertip(q) - head_to_torso(mark_head, q[0], q[1]);
    let pen = arm_clear_of_head(q, 0.008);
    [e.x, e.y, e.z, 0.004 * q[0], 0.004 * q[1], 0.5 * pen]
}

fn clamp(q: &mut Reach, lim: &[[f64; 2]; 5]) {
    for (v, l) in q.iter_mut().zip(lim) {
        *v = v.clamp(l[0], l[1]);
    }
}

/// Levenberg-Marquardt with a numeric Jacobian, projected onto the joint limits.
fn solve_from(seed: Reach, mark_head: &Point3<f64>, lim: &[[f64; 2]; 5]) -> Reach {
    use nalgebra::{SMatrix, SVector};
    let mut q = seed;
    clamp(&mut q, lim);
    let cost = |q: &Reach| residuals(q, mark_head).iter().map(|r| r * r).sum::<f64>();
    let mut lambda = 1e-3;
    let mut c = cost(&q);
    for _ in 0..200 {
        let r0 = SVector::<f64, 6>::from(residuals(&q, mark_head));
        let mut jac = SMatrix::<f64, 6, 5>::zeros();
        for k in 0..5 {
            let mut qk = q;
            let h = 1e-6;
            qk[k] += h;
            let rk = SVector::<f64, 6>::from(residuals(&qk, mark_head));
            jac.set_column(k, &((rk - r0) / h));
        }
        let jt = jac.transpose();
        let g = jt * r0;
        let mut improved = false;
        for _ in 0..10 {
            let mut a = jt * jac;
            for k in 0..5 {
                a[(k, k)] += lambda * (1.0 + a[(k, k)]);
            }
            let Some(step) = a.lu().solve(&(-g)) else { break };
            let mut qn = q;
            for k in 0..5 {
                qn[k] += step[k];
            }
            clamp(&mut qn, lim);
            let cn = cost(&qn);
            if cn < c {
                q = qn;
                improved = (c - cn) > 1e-14;
                c = cn;
                lambda = (lambda * 0.3).max(1e-9);
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    q
}

/// Position error below which the IK accepts a posture.
pub const IK_TOLERANCE_M: f64 = 0.002;

/// Finds the five reach angles that put the left fingertip on `mark_head` (a point in the head
/// frame), inside the joint limits, with the elbow and wrist clear of the head. Deterministic.
pub fn ik_touch(mark_head: &Point3<f64>) -> Result<Reach, IkError> {
    if !mark_head.coords.iter().all(|v| v.is_finite()) {
        return Err(IkError::NotFinite);
    }
    let lim = reach_limits();
    // Seeds from a neutral head outwards, in groups by head yaw; within the first group that
    // has collision-free solutions the one with the lowest cost wins (fewer jumps between
    // neighbouring marks than "first found"). Else the closest miss is reported.
    let cost = |q: &Reach| residuals(q, mark_head).iter().map(|r| r * r).sum::<f64>();
    let mut closest_miss = f64::INFINITY;
    for yaw in [0.0, -0.5, 0.5, -1.0, 1.0] {
        let mut best: Option<(f64, Reach)> = None;
        for pitch in [0.0, 0.3, -0.3] {
            for arm in [[-0.3, 0.0, -1.3], [0.2, 0.2, -1.5], [-0.6, -0.2, -1.1]] {
                let q = solve_from([yaw, pitch, arm[0], arm[1], arm[2]], mark_head, &lim);
                let err = touch_distance(&q, mark_head);
                closest_miss = closest_miss.min(err);
                if err <= IK_TOLERANCE_M && arm_clear_of_head(&q, 0.0) == 0.0 {
                    let c = cost(&q);
                    if best.is_none_or(|b| c < b.0) {
                        best = Some((c, q));
                    }
                }
            }
        }
        if let Some((_, q)) = best {
            return Ok(q);
        }
    }
    Err(IkError::Unreachable { best_mm: closest_miss * 1e3 })
}

/// The reach vector as f32 in [`msr_shared::joints::REACH_JOINTS`] order.
pub fn to_f32(q: &Reach) -> [f32; 5] {
    q.map(|v| v as f32)
}

/// The joint of each reach entry, for messages.
pub const REACH_JOINTS: [Joint; 5] = msr_shared::joints::REACH_JOINTS;

#[cfg(test)]
mod tests;
