//! Writes example frames to `target/sim-pictures/`: both robots at a few head angles, without
//! and with marks (each kind), their face templates, and a reach pose from the IK.
//! `cargo run -p msr-sim --example sim_pictures`
use msr_sim::body::{self, BodyPose};
use msr_sim::kin::{self, LeftArm};
use msr_sim::marks::{Mark, KINDS};
use msr_sim::render::{Renderer, Variation};
use msr_sim::Robot;
use rand::SeedableRng;

fn main() -> anyhow::Result<()> {
    let out = std::path::Path::new("target/sim-pictures");
    std::fs::create_dir_all(out)?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2026);
    let deg = 1f64.to_radians();
    for robot in Robot::ALL {
        let r = Renderer::new(robot);
        r.template().save(out.join(format!("{robot}_template.png")))?;
        for (name, yaw, pitch) in [("center", 0.0, 0.0), ("yaw+5", 5.0 * deg, 0.0), ("yaw-5_pitch+5", -5.0 * deg, 5.0 * deg), ("yaw+20", 20.0 * deg, 0.0)] {
            let pose = BodyPose::head(yaw, pitch);
            let v = Variation::random(&mut rng);
            r.render(&pose, None, &v).rgb.save(out.join(format!("{robot}_{name}.png")))?;
        }
        for (i, kind) in KINDS.iter().enumerate() {
            let yaw = [-4.0, 0.0, 4.0, 2.0, -2.0][i] * deg;
            let pitch = [3.0, -3.0, 0.0, 4.0, -4.0][i] * deg;
            let v = Variation::random(&mut rng);
            let (m, f) = loop {
                let m = Mark::random_of_kind(kind, &mut rng).unwrap();
                let f = r.render(&BodyPose::head(yaw, pitch), Some(&m), &v);
                if f.mark.as_ref().unwrap().contrast >= msr_sim::dataset::MIN_MARK_CONTRAST {
                    break (m, f);
                }
            };
            let path = out.join(format!("{robot}_mark_{kind}_{}.png", m.colour));
            f.rgb.save(&path)?;
            f.mark.unwrap().mask.save(out.join(format!("{robot}_mark_{kind}_mask.png")))?;
        }
        // Reaching for a mark on the forehead: the left hand touches it, the head stays nearly straight.
        let p = body::face_point(-0.014, 0.077).unwrap();
        let q = kin::ik_touch(&p)?;
        let mut pose = BodyPose::head(q[0], q[1]);
        pose.left_arm = LeftArm::from_reach(&q);
        let mark = Mark::of_kind("rectangle", [-0.014, 0.077], &mut rng).unwrap();
        r.render(&pose, Some(&mark), &Variation::CLEAN).rgb.save(out.join(format!("{robot}_reach.png")))?;
    }
    let mut names: Vec<_> = std::fs::read_dir(out)?.map(|e| e.unwrap().path().display().to_string()).collect();
    names.sort();
    for n in names {
        println!("{n}");
    }
    Ok(())
}
