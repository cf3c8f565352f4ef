//! The one geometric model of the robot, the mirror and the camera, shared by the renderer, the
//! mark placement and the kinematics: the body is a set of ellipsoids placed by forward
//! kinematics, the mirror is the plane x = [`MIRROR_X`] of the torso frame, and the camera is the
//! head's top camera (a pinhole with Nao's 60.97 degree horizontal field of view).
use crate::kin::{self, LeftArm, HEAD_ELLIPSOID};
use nalgebra::{Isometry3, Matrix3, Point3, Vector3};

/// Camera frame width, pixels.
pub const WIDTH: u32 = 320;
/// Camera frame height, pixels.
pub const HEIGHT: u32 = 240;
/// Nao's top camera: 60.97 degrees across 320 pixels.
pub const FOCAL_PX: f64 = 271.57;
/// Principal point's x, pixels (the frame's centre).
pub const CX: f64 = (WIDTH as f64 - 1.0) / 2.0;
/// Principal point's y, pixels (the frame's centre).
pub const CY: f64 = (HEIGHT as f64 - 1.0) / 2.0;
/// The mirror plane in the torso frame, chosen so that the face fills a 75 x 58 crop.
pub const MIRROR_X: f64 = 0.29;

/// Where marks go, in head-frame (y, z): the front of the face below the red cap and between
/// the ears. Each mark's whole extent stays inside (see `marks`). Every point here is reachable by
/// [`kin::ik_touch`] (tested).
pub const FACE_Y: [f64; 2] = [-0.042, 0.042];
/// Where marks go in head-frame z, metres (see [`FACE_Y`]).
pub const FACE_Z: [f64; 2] = [0.030, 0.100];

/// Largest head angle a dataset may use (radians): beyond it the face leaves the usual crop area.
pub const MAX_DATASET_HEAD_ANGLE: f64 = 0.35;

/// The face crop size (the published template).
pub const CROP_W: u32 = 75;
/// Height of the face crop, pixels.
pub const CROP_H: u32 = 58;
/// Head-frame point at the centre of the face crop.
pub const CROP_CENTRE_HEAD: [f64; 3] = [0.06, 0.0, 0.052];

/// Which part of the body a primitive is; the looks colour by part.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Part {
    /// The head shell.
    Head,
    /// The neck.
    Neck,
    /// The torso.
    Torso,
    /// A shoulder.
    Shoulder,
    /// An upper arm.
    UpperArm,
    /// A forearm.
    Forearm,
}

/// An ellipsoid: `local = to_unit * (world - centre)` maps it onto the unit sphere.
#[derive(Clone, Copy, Debug)]
pub struct Ellipsoid {
    /// Which body part this is.
    pub part: Part,
    /// Centre in the torso frame.
    pub centre: Point3<f64>,
    /// Maps a point's offset from the centre into the unit sphere's frame.
    pub to_unit: Matrix3<f64>,
    /// Local frame of the part (torso <- part), for textures.
    pub frame: Isometry3<f64>,
    centre_local: [f64; 3],
    radii: [f64; 3],
}

impl Ellipsoid {
    fn new(part: Part, frame: Isometry3<f64>, centre_local: [f64; 3], radii: [f64; 3]) -> Self {
        let r = frame.rotation.to_rotation_matrix();
        let inv_r = Matrix3::from_diagonal(&Vector3::new(1.0 / radii[0], 1.0 / radii[1], 1.0 / radii[2]));
        Ellipsoid {
            part,
            centre: frame * Point3::from(Vector3::from(centre_local)),
            to_unit: inv_r * r.matrix().transpose(),
            frame,
            centre_local,
            radii,
        }
    }

    /// Corners of the ellipsoid's bounding box, in the torso frame.
    pub fn corners(&self) -> [Point3<f64>; 8] {
        let (c, r) = (self.centre_local, self.radii);
        core::array::from_fn(|i| {
            let s = |bit: usize| if i & (1 << bit) == 0 { -1.0 } else { 1.0 };
            self.frame * Point3::new(c[0] + s(0) * r[0], c[1] + s(1) * r[1], c[2] + s(2) * r[2])
        })
    }

    /// Nearest hit `t > 0` of the ray `o + t d`.
    #[inline]
    pub fn hit(&self, o: &Point3<f64>, d: &Vector3<f64>) -> Option<f64> {
        let lo = self.to_unit * (o - self.centre);
        let ld = self.to_unit * d;
        let a = ld.norm_squared();
        let b = lo.dot(&ld);
        let c = lo.norm_squared() - 1.0;
        let disc = b * b - a * c;
        if disc < 0.0 {
            return None;
        }
        let s = disc.sqrt();
        let t0 = (-b - s) / a;
        if t0 > 1e-9 {
            return Some(t0);
        }
        let t1 = (-b + s) / a;
        (t1 > 1e-9).then_some(t1)
    }

    /// Outward unit normal at a surface point.
    #[inline]
    pub fn normal(&self, p: &Point3<f64>) -> Vector3<f64> {
        let l = self.to_unit * (p - self.centre);
        (self.to_unit.transpose() * l).normalize()
    }
}

/// The robot's pose as far as the picture goes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BodyPose {
    /// HeadYaw, radians.
    pub head_yaw: f64,
    /// HeadPitch, radians.
    pub head_pitch: f64,
    /// The left arm's joints.
    pub left_arm: LeftArm,
    /// The right arm's joints, in the left arm's convention mirrored across the torso's x-z plane.
    pub right_arm: LeftArm,
    /// How the left arm differs from its drawing (the right arm, which never reaches, is drawn
    /// exact).
    pub arm_error: kin::ArmError,
}

impl BodyPose {
    /// Head at the given angles, both arms at home.
    pub fn head(yaw: f64, pitch: f64) -> Self {
        BodyPose {
            head_yaw: yaw,
            head_pitch: pitch,
            left_arm: LeftArm::home(),
            right_arm: LeftArm::home(),
            arm_error: kin::ArmError::EXACT,
        }
    }
}

/// An ellipsoid along `a` -> `b`, `thick` across. It reaches `thick / 2` past `a`, and past `b`
/// too unless `ends_at_b`: the forearm ends at the fingertip, so that what the camera sees touch
/// the face is the point the touch judge measures.
fn segment(part: Part, a: Point3<f64>, b: Point3<f64>, thick: f64, ends_at_b: bool) -> Ellipsoid {
    let axis = b - a;
    let len = axis.norm().max(1e-6);
    let rot = nalgebra::UnitQuaternion::rotation_between(&Vector3::x(), &axis)
        .unwrap_or_else(|| nalgebra::UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI));
    let (past_a, past_b) = (thick * 0.5, if ends_at_b { 0.0 } else { thick * 0.5 });
    let mid = a + axis * ((len + past_b - past_a) / 2.0 / len);
    let frame = Isometry3::from_parts(mid.coords.into(), rot);
    Ellipsoid::new(part, frame, [0.0; 3], [(len + past_a + past_b) / 2.0, thick, thick])
}

/// The body's ellipsoids at a pose, head first.
pub fn ellipsoids(pose: &BodyPose) -> Vec<Ellipsoid> {
    let head = kin::head_pose(pose.head_yaw, pose.head_pitch);
    let torso = Isometry3::identity();
    let mut v = vec![
        Ellipsoid::new(Part::Head, head, HEAD_ELLIPSOID.0, HEAD_ELLIPSOID.1),
        Ellipsoid::new(Part::Neck, torso, [0.0, 0.0, 0.115], [0.025, 0.025, 0.03]),
        Ellipsoid::new(Part::Torso, torso, [0.0, 0.0, 0.03], [0.055, 0.080, 0.095]),
    ];
    for (arm, side, e) in [(&pose.left_arm, 1.0, pose.arm_error), (&pose.right_arm, -1.0, kin::ArmError::EXACT)] {
        let p = kin::arm_points_of(arm, side, &e);
        v.push(Ellipsoid::new(
            Part::Shoulder,
            Isometry3::translation(p.shoulder.x, p.shoulder.y, p.shoulder.z),
            [0.0; 3],
            [0.038, 0.036, 0.034],
        ));
        v.push(segment(Part::UpperArm, p.shoulder, p.elbow, 0.026, false));
        v.push(segment(Part::Forearm, p.elbow, p.fingertip, 0.022, true));
    }
    v
}

/// The head-surface point (head frame) in front of head-frame (y, z), if the ray along -x from
/// the front meets the head.
pub fn face_point(y: f64, z: f64) -> Option<Point3<f64>> {
    let (c, r) = HEAD_ELLIPSOID;
    let s = 1.0 - ((y - c[1]) / r[1]).powi(2) - ((z - c[2]) / r[2]).powi(2);
    (s > 0.0).then(|| Point3::new(c[0] + r[0] * s.sqrt(), y, z))
}

/// Pixel (x right, y down; pixel centres at integers) where the camera sees a torso-frame point
/// in the mirror, if it is in front of the camera.
pub fn project_torso(p: &Point3<f64>, yaw: f64, pitch: f64) -> Option<[f64; 2]> {
    let mirrored = Point3::new(2.0 * MIRROR_X - p.x, p.y, p.z);
    let c = kin::camera_pose(yaw, pitch).inverse() * mirrored;
    (c.x > 1e-6).then(|| [CX - FOCAL_PX * c.y / c.x, CY - FOCAL_PX * c.z / c.x])
}

/// Pixel of a head-frame point at these head angles.
pub fn project_head(p: &Point3<f64>, yaw: f64, pitch: f64) -> Option<[f64; 2]> {
    project_torso(&kin::head_to_torso(p, yaw, pitch), yaw, pitch)
}

/// Top-left corner of the 75 x 58 face crop at these head angles: the crop centred on
/// [`CROP_CENTRE_HEAD`], clamped into the frame.
pub fn crop_origin(yaw: f64, pitch: f64) -> [u32; 2] {
    let c = project_head(&Point3::from(Vector3::from(CROP_CENTRE_HEAD)), yaw, pitch)
        .unwrap_or([CX, CY]);
    let x = (c[0] - (CROP_W as f64 - 1.0) / 2.0).round().clamp(0.0, (WIDTH - CROP_W) as f64);
    let y = (c[1] - (CROP_H as f64 - 1.0) / 2.0).round().clamp(0.0, (HEIGHT - CROP_H) as f64);
    [x as u32, y as u32]
}
