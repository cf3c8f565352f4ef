use super::*;
use crate::body;
use std::f64::consts::FRAC_PI_2;

fn close(a: Point3<f64>, b: [f64; 3], tol: f64) {
    let d = (a.coords - Vector3::from(b)).norm();
    assert!(d < tol, "{a:?} vs {b:?}: {d}");
}

fn arm(sp: f64, sr: f64, ey: f64, er: f64) -> LeftArm {
    LeftArm { shoulder_pitch: sp, shoulder_roll: sr, elbow_yaw: ey, elbow_roll: er, wrist_yaw: 0.0 }
}

#[test]
fn camera_by_hand() {
    // Straight: torso -> neck 126.5 mm, head -> camera (58.71, 0, 63.64) mm.
    close(camera_pose(0.0, 0.0) * Point3::origin(), [0.05871, 0.0, 0.19014], 1e-12);
    // Yaw 90 degrees left: the camera swings to +y.
    close(camera_pose(FRAC_PI_2, 0.0) * Point3::origin(), [0.0, 0.05871, 0.19014], 1e-12);
    // Pitch 90 degrees down: forward offset becomes down, up offset becomes forward.
    close(camera_pose(0.0, FRAC_PI_2) * Point3::origin(), [0.06364, 0.0, 0.1265 - 0.05871], 1e-12);
    // The optical axis follows: yaw 90 looks along +y, pitch 90 looks down.
    let ax = camera_pose(FRAC_PI_2, 0.0).rotation * Vector3::x();
    assert!((ax - Vector3::y()).norm() < 1e-12);
    let ax = camera_pose(0.0, FRAC_PI_2).rotation * Vector3::x();
    assert!((ax + Vector3::z()).norm() < 1e-12);
}

#[test]
fn arm_by_hand() {
    // All zero: the arm points straight forward from the shoulder.
    let p = arm_points(&arm(0.0, 0.0, 0.0, 0.0), 1.0);
    close(p.shoulder, [0.0, 0.098, 0.100], 1e-12);
    close(p.elbow, [0.105, 0.113, 0.100], 1e-12);
    close(p.wrist, [0.16095, 0.113, 0.100], 1e-12);
    close(p.fingertip, [0.2187, 0.113, 0.08769], 1e-12);
    // Shoulder pitch 90 degrees: the arm hangs down, the hand's -z offset points backwards.
    let p = arm_points(&arm(FRAC_PI_2, 0.0, 0.0, 0.0), 1.0);
    close(p.elbow, [0.0, 0.113, -0.005], 1e-12);
    close(p.fingertip, [-0.01231, 0.113, 0.1 - 0.2187], 1e-12);
    // Elbow roll -90 degrees with elbow yaw 0: the forearm turns inwards (-y).
    let p = arm_points(&arm(0.0, 0.0, 0.0, -FRAC_PI_2), 1.0);
    close(p.wrist, [0.105, 0.113 - 0.05595, 0.100], 1e-12);
    close(p.fingertip, [0.105, 0.113 - 0.1137, 0.1 - 0.01231], 1e-12);
    // Shoulder roll 90 degrees: the arm points left.
    let p = arm_points(&arm(0.0, FRAC_PI_2, 0.0, 0.0), 1.0);
    close(p.elbow, [-0.015, 0.098 + 0.105, 0.100], 1e-12);
    // The mirrored right arm is the left one reflected in the y = 0 plane.
    let l = arm(0.4, 0.3, -0.7, -1.1);
    let (pl, pr) = (arm_points(&l, 1.0), arm_points(&l.mirrored(), -1.0));
    for (a, b) in [(pl.elbow, pr.elbow), (pl.wrist, pr.wrist), (pl.fingertip, pr.fingertip)] {
        close(b, [a.x, -a.y, a.z], 1e-12);
    }
}

#[test]
fn home_posture_hangs_the_hand_low() {
    let f = fingertip(&home());
    // Forearm bent forwards over the lap: in front of the torso, below the shoulder, left side.
    assert!(f.z < -0.05 && f.x > 0.03 && f.y > 0.03, "{f:?}");
}

#[test]
fn touch_judge_by_hand() {
    // Arm straight forward (all zero) and the head turned: put a "mark" 15 mm and 25 mm from
    // the fingertip, given in the head frame of that pose.
    let q: Reach = [0.3, -0.2, 0.0, 0.0, -0.0349066 - 1e-3];
    let f = fingertip(&q);
    let head = head_pose(q[0], q[1]);
    let near = head.inverse() * (f + Vector3::new(0.0, 0.015, 0.0));
    let far = head.inverse() * (f + Vector3::new(0.0, 0.0, 0.025));
    assert!((touch_distance(&q, &near) - 0.015).abs() < 1e-12);
    assert!(judge_touch(&[q, q], &near).0);
    assert!(!judge_touch(&[q, q], &far).0);
    // The mark moves with the head: the same arm with the head turned away is no touch.
    let moved = [q[0] + 0.5, q[1], q[2], q[3], q[4]];
    assert!(!judge_touch(&[q, moved], &near).0);
    // Nothing held is no touch; a NaN sample spoils the hold.
    assert!(!judge_touch(&[], &near).0);
    let nan = [q[0], f64::NAN, q[2], q[3], q[4]];
    let (touched, worst) = judge_touch(&[q, nan, q], &near);
    assert!(!touched && worst.is_nan());
}

#[test]
fn ik_reaches_the_whole_mark_area() {
    let lim = msr_shared::joints::REACH_JOINTS.map(|j| j.limits().unwrap());
    let n = 7;
    for iy in 0..=n {
        for iz in 0..=n {
            let y = body::FACE_Y[0] + (body::FACE_Y[1] - body::FACE_Y[0]) * iy as f64 / n as f64;
            let z = body::FACE_Z[0] + (body::FACE_Z[1] - body::FACE_Z[0]) * iz as f64 / n as f64;
            let p = body::face_point(y, z).expect("on the face");
            let q = ik_touch(&p).unwrap_or_else(|e| panic!("({y}, {z}): {e}"));
            assert!(touch_distance(&q, &p) <= IK_TOLERANCE_M, "({y}, {z})");
            // Inside the limits, also as f32 (what goes on the wire).
            for (v, l) in to_f32(&q).iter().zip(&lim) {
                assert!(*v >= l.min && *v <= l.max, "({y}, {z}): {q:?}");
            }
            assert_eq!(arm_clear_of_head(&q, 0.0), 0.0, "arm through the head at ({y}, {z})");
            assert!(judge_touch(&[q], &p).0);
        }
    }
}

#[test]
fn ik_refuses_what_it_cannot_reach() {
    // Far above the head and far away.
    assert!(matches!(ik_touch(&Point3::new(0.0, 0.0, 0.4)), Err(IkError::Unreachable { .. })));
    assert!(matches!(ik_touch(&Point3::new(1.0, 0.0, 0.0)), Err(IkError::Unreachable { .. })));
    assert_eq!(ik_touch(&Point3::new(f64::NAN, 0.0, 0.0)), Err(IkError::NotFinite));
}

#[test]
fn ik_is_deterministic() {
    let p = body::face_point(0.02, 0.07).unwrap();
    assert_eq!(ik_touch(&p).unwrap(), ik_touch(&p).unwrap());
}

#[test]
fn an_arm_unlike_its_drawing_by_hand() {
    // Arm straight forward (all zero): shoulder -> elbow along x by the upper arm, then the
    // forearm, then the hand offset.
    let a = arm(0.0, 0.0, 0.0, 0.0);
    let exact = arm_points(&a, 1.0);
    let same = arm_points_of(&a, 1.0, &ArmError::EXACT);
    assert_eq!((exact.elbow, exact.fingertip), (same.elbow, same.fingertip));
    // The forearm 10 % longer: the fingertip 5.595 mm further forward, the elbow unmoved.
    let long = ArmError { length: [1.0, 1.1, 1.0], ..ArmError::EXACT };
    let p = arm_points_of(&a, 1.0, &long);
    close(p.elbow, exact.elbow.coords.into(), 1e-12);
    close(p.fingertip, (exact.fingertip.coords + Vector3::new(0.1 * LOWER_ARM_X, 0.0, 0.0)).into(), 1e-12);
    // A shoulder-roll zero off by 1 degree: the arm as if commanded 1 degree more.
    let z = 1f64.to_radians();
    let off = ArmError { zero_rad: [0.0, z, 0.0, 0.0, 0.0], ..ArmError::EXACT };
    let turned = arm_points(&arm(0.0, z, 0.0, 0.0), 1.0);
    close(arm_points_of(&a, 1.0, &off).fingertip, turned.fingertip.coords.into(), 1e-12);
    // The judge measures the arm's own fingertip, with its radius.
    let q: Reach = [0.3, -0.2, 0.0, 0.0, -0.0349066 - 1e-3];
    let mark = head_pose(q[0], q[1]).inverse() * fingertip(&q);
    assert!(judge_touch_of(&[q], &mark, &ArmError::EXACT, 0.001).0);
    let (touched, worst) = judge_touch_of(&[q], &mark, &long, 0.010);
    assert!((worst - (fingertip_of(&q, &long) - fingertip(&q)).norm()).abs() < 1e-12);
    assert_eq!(touched, worst <= 0.010);
    assert!(worst > 0.004, "a 10 % longer forearm moves the fingertip {worst} m");
}
