//! Speed of the mirror world on one core: rendering, dataset writing, simulated vs wall time.
//! `cargo run -p msr-sim --example sim_bench [--release] [-- world]` (`world`: only the world run)
use msr_sim::body::BodyPose;
use msr_sim::camera::Camera;
use msr_shared::host_port::HostPort;
use msr_sim::dataset::{write_dataset, DatasetConfig};
use msr_sim::link::LinkEnd;
use msr_sim::marks::Mark;
use msr_sim::render::{Renderer, Variation};
use msr_sim::world::{run, Flow, World, WorldConfig};
use msr_sim::Robot;
use rand::{Rng, SeedableRng};
use std::time::Instant;

/// CPU time of this thread (robust against other load on the machine).
fn cpu_s() -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<f64>().ok())
        .map_or(f64::NAN, |ns| ns * 1e-9)
}

/// CPU time of the whole process, all threads (10 ms resolution).
fn process_cpu_s() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the command name (which may hold spaces): utime and stime are 14 and 15.
    let rest = stat.rsplit_once(')').map_or("", |r| r.1);
    let f: Vec<&str> = rest.split_whitespace().collect();
    let num = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(f64::NAN);
    // `rest` starts at field 3 (state).
    (num(14 - 3) + num(15 - 3)) / 100.0
}

fn main() -> anyhow::Result<()> {
    let only_world = std::env::args().any(|a| a == "world");
    let a = 5f64.to_radians();
    for robot in Robot::ALL {
        if only_world {
            break;
        }
        let r = Renderer::new(robot);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let (t, c) = (Instant::now(), cpu_s());
        let mut marked = 0;
        for i in 0..1300u32 {
            let pose = BodyPose::head(rng.gen_range(-a..a), rng.gen_range(-a..a));
            let v = Variation::random(&mut rng);
            let mark = i.is_multiple_of(5).then(|| Mark::random(&mut rng));
            marked += r.render(&pose, mark.as_ref(), &v).mark.is_some() as u32;
        }
        let (s, cs) = (t.elapsed().as_secs_f64(), cpu_s() - c);
        println!(
            "render {robot}: 1300 frames ({marked} marked) in {s:.2} s wall, {cs:.2} s CPU = {:.0} frames/s on one core",
            1300.0 / cs
        );
    }
    let dir = std::env::temp_dir().join("msr-sim-bench");
    for robot in Robot::ALL {
        if only_world {
            break;
        }
        let (t, c) = (Instant::now(), cpu_s());
        write_dataset(&DatasetConfig::paper(robot, 1), &dir)?;
        println!(
            "dataset {robot}: 1300 frames + 100 reach pairs written in {:.2} s wall, {:.2} s CPU",
            t.elapsed().as_secs_f64(),
            cpu_s() - c
        );
    }
    let _ = std::fs::remove_dir_all(&dir);

    // 20 s of world time: servos, the host link, a camera at 10 frames/s streaming crops, and a
    // firmware stand-in that reads everything and commands the head every 10 ms.
    for mode in [0, 1, 2] {
    let face_only = mode == 1;
    let mut cam = Camera::new(Robot::Red, 3);
    let mut port = HostPort::default();
    let mut fw = |now: u64, h: &mut LinkEnd, s: &mut LinkEnd| {
        let _ = (h.receive(), s.receive());
        if now.is_multiple_of(10_000) {
            let mut t = heapless::Vec::new();
            let yaw = 0.05 * ((now as f32) * 1e-6).sin();
            t.push(msr_shared::msg::JointTarget { joint: msr_shared::Joint::HeadYaw, position: yaw }).unwrap();
            let m = msr_shared::msg::BoardToServo::Targets { time_ms: (now / 1000) as u32, targets: t };
            s.send(&msr_shared::frame::encode_message_vec(0, &m).unwrap());
        }
    };
    let cpu0 = process_cpu_s();
    let (_, rep) = run(&WorldConfig::default(), &mut fw, |w: &mut World| {
        if mode < 2 && w.now_us.is_multiple_of(100_000) {
            let c = if face_only { cam.capture_face(w, None) } else { cam.capture(w, None) };
            w.host.send(&c.wire(&mut port).expect("a face crop fits"));
        }
        Flow::Continue
    }, 20_000_000)?;
    let cpu = process_cpu_s() - cpu0;
    println!(
        "world ({}): {:.1} s simulated in {:.2} s wall, {cpu:.2} s CPU of both threads ({} ticks of 1 ms): {:.0}x real time",
        ["full frames", "face-only frames", "no frames"][mode],
        rep.end_us as f64 * 1e-6, rep.wall_s, rep.ticks, rep.speedup
    );
    }
    Ok(())
}
