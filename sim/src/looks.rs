//! The two robots' looks: albedo, gloss and LED glow of every body part, as functions of a point
//! in the part's own frame (so that textures move with the part).
//!
//! - `red`: the real red Nao: white shell, red cap, ear covers, shoulders and chest plate,
//!   round eyes with white-blue LED rings, a mouth slot.
//! - `skin`: a very different robot: matte grey covers tiled with a grid of round skin taxels
//!   (dark sensors with copper rims), green eye LEDs, no red at all.
use crate::body::Part;
use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
/// The robots the sim draws.
pub enum Robot {
    /// The published red Nao.
    Red,
    /// A robot in matte grey covers tiled with round skin taxels.
    Skin,
}

impl Robot {
    /// Every robot.
    pub const ALL: [Robot; 2] = [Robot::Red, Robot::Skin];

    /// The robot's name on the command line and in datasets.
    pub fn name(self) -> &'static str {
        match self {
            Robot::Red => "red",
            Robot::Skin => "skin",
        }
    }
}

impl std::str::FromStr for Robot {
    type Err = String;
    fn from_str(s: &str) -> Result<Robot, String> {
        match s {
            "red" => Ok(Robot::Red),
            "skin" => Ok(Robot::Skin),
            _ => Err(format!("unknown robot {s:?}: expected red or skin")),
        }
    }
}

impl std::fmt::Display for Robot {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Direction towards the key light (torso frame): in front, above and a little to the left.
pub const LIGHT: Vector3<f64> = Vector3::new(1.0, 0.35, 0.9);
/// Share of light that reaches every surface.
pub const AMBIENT: f32 = 0.45;

/// How a surface point reflects and glows, colours in 0..1.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Surface {
    /// Diffuse colour, linear RGB.
    pub albedo: [f32; 3],
    /// Specular strength.
    pub specular: f32,
    /// Specular exponent.
    pub shininess: i32,
    /// Light the material emits, linear RGB.
    pub emission: [f32; 3],
}

impl Surface {
    const fn plastic(albedo: [f32; 3]) -> Surface {
        Surface { albedo, specular: 0.35, shininess: 24, emission: [0.0; 3] }
    }
    const fn matte(albedo: [f32; 3]) -> Surface {
        Surface { albedo, specular: 0.06, shininess: 6, emission: [0.0; 3] }
    }
    /// Paper or paint on the face: a matte colour.
    pub fn paint(rgb: [u8; 3]) -> Surface {
        Surface::matte(rgb.map(|c| c as f32 / 255.0))
    }
    fn led(colour: [f32; 3], level: f32) -> Surface {
        Surface {
            albedo: [0.05; 3],
            specular: 0.2,
            shininess: 30,
            emission: colour.map(|c| c * level),
        }
    }
}

const WHITE: [f32; 3] = [0.93, 0.91, 0.87];
const RED: [f32; 3] = [0.80, 0.07, 0.08];
const DARK: [f32; 3] = [0.06, 0.06, 0.07];
const GREY_COVER: [f32; 3] = [0.52, 0.54, 0.57];
const TAXEL: [f32; 3] = [0.16, 0.15, 0.14];
const COPPER: [f32; 3] = [0.72, 0.48, 0.28];

/// Eye centres in the head frame (y, z).
pub const EYES: [[f64; 2]; 2] = [[0.028, 0.050], [-0.028, 0.050]];

/// A robot's look at one frame's LED level.
pub struct Look {
    robot: Robot,
    eye_led: f32,
}

impl Look {
    /// The look of `robot`, its eye LEDs at brightness `eye_led`.
    pub fn of(robot: Robot, eye_led: f32) -> Look {
        Look { robot, eye_led: eye_led.clamp(0.0, 1.0) }
    }

    /// The surface at a point given in the part's frame.
    pub fn surface(&self, part: Part, p: &Point3<f64>) -> Surface {
        match self.robot {
            Robot::Red => self.red(part, p),
            Robot::Skin => self.skin(part, p),
        }
    }

    fn red(&self, part: Part, p: &Point3<f64>) -> Surface {
        match part {
            Part::Head => {
                if p.x > 0.0 {
                    if let Some(s) = self.eye(p, [0.75, 0.88, 1.0], 0.0075, 0.0112) {
                        return s;
                    }
                    if p.y.abs() < 0.009 && (p.z - 0.018).abs() < 0.0025 {
                        return Surface::matte([0.25, 0.25, 0.27]);
                    }
                }
                let cap = p.z > 0.095 - 8.0 * p.y * p.y;
                let ear = p.y.abs() > 0.05 && p.x * p.x + (p.z - 0.055) * (p.z - 0.055) < 0.028 * 0.028;
                Surface::plastic(if cap || ear { RED } else { WHITE })
            }
            Part::Neck => Surface::matte([0.3, 0.3, 0.32]),
            Part::Torso => {
                let chest = p.x > 0.02 && p.y.abs() < 0.045 && (-0.01..0.065).contains(&p.z);
                let button = p.x > 0.02 && p.y * p.y + (p.z - 0.03) * (p.z - 0.03) < 0.012 * 0.012;
                if button {
                    Surface::plastic([0.75, 0.8, 0.85])
                } else {
                    Surface::plastic(if chest { RED } else { WHITE })
                }
            }
            Part::Shoulder => Surface::plastic(RED),
            Part::UpperArm | Part::Forearm => Surface::plastic(WHITE),
        }
    }

    fn skin(&self, part: Part, p: &Point3<f64>) -> Surface {
        match part {
            Part::Head => {
                if p.x > 0.0 {
                    if let Some(s) = self.eye(p, [0.25, 1.0, 0.45], 0.0055, 0.009) {
                        return s;
                    }
                }
                if p.z > 0.105 {
                    return Surface::matte([0.35, 0.36, 0.38]);
                }
                if p.x > 0.0 {
                    taxels(p.y, p.z, 0.011)
                } else {
                    Surface::matte(GREY_COVER)
                }
            }
            Part::Neck => Surface::matte([0.25, 0.25, 0.26]),
            Part::Torso => {
                if p.x > 0.0 {
                    taxels(p.y, p.z, 0.014)
                } else {
                    Surface::matte(GREY_COVER)
                }
            }
            Part::Shoulder => Surface::matte([0.38, 0.39, 0.41]),
            Part::UpperArm | Part::Forearm => taxels(p.x, p.y + p.z, 0.012),
        }
    }

    /// An eye: LED disc of radius `led`, dark rim out to `rim`, a dark pupil.
    fn eye(&self, p: &Point3<f64>, colour: [f32; 3], led: f64, rim: f64) -> Option<Surface> {
        for [ey, ez] in EYES {
            let r = ((p.y - ey).powi(2) + (p.z - ez).powi(2)).sqrt();
            if r < 0.0025 {
                return Some(Surface::plastic(DARK));
            }
            if r < led {
                return Some(Surface::led(colour, self.eye_led));
            }
            if r < rim {
                return Some(Surface::plastic(DARK));
            }
        }
        None
    }
}

/// A square grid of round taxels (dark sensor, copper rim) on a grey cover.
fn taxels(u: f64, v: f64, pitch: f64) -> Surface {
    let du = u / pitch - (u / pitch).round();
    let dv = v / pitch - (v / pitch).round();
    let r = (du * du + dv * dv).sqrt() * pitch;
    if r < 0.30 * pitch {
        Surface::matte(TAXEL)
    } else if r < 0.40 * pitch {
        Surface::plastic(COPPER)
    } else {
        Surface::matte(GREY_COVER)
    }
}

/// The plain wall behind the robot, seen in the mirror: off-white, a little darker at the
/// bottom and the corners. `u`, `v` in 0..1 across the frame.
pub fn background(u: f32, v: f32) -> [f32; 3] {
    let vignette = 1.0 - 0.12 * ((u - 0.5).powi(2) + (v - 0.45).powi(2));
    let k = (0.90 - 0.06 * v) * vignette;
    [k, k, k * 0.97]
}
