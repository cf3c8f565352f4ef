//! What stands in front of the robot: its mirror image, another robot of the same look, or its
//! own mirror image seen through a video delay. The self gate must pass the first and never the
//! others. Each trial draws its scene's randomness (babbling or not, the other's schedule, the
//! delay) from a stream of its own, so the mirror scene's trials stay those of runs without scenes.
use msr_sim::body::BodyPose;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use std::collections::VecDeque;

/// The scene, as `msr mirror-test --scene` names it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Scene {
    /// The robot's own mirror image (the mirror test proper).
    #[default]
    Mirror,
    /// A second robot of the same look where the mirror image would be, holding still or
    /// babbling its head on its own schedule; marks go on its face.
    Other,
    /// The robot's own mirror image, seen through a video delay drawn from
    /// [`DELAY_RANGE_US`].
    Delayed,
}

impl Scene {
    /// The scene's name as the command line and each trial's JSON spell it.
    pub fn name(self) -> &'static str {
        match self {
            Scene::Mirror => "mirror",
            Scene::Other => "other",
            Scene::Delayed => "delayed",
        }
    }
}

/// The delayed scene's video delay, drawn uniformly per trial.
pub const DELAY_RANGE_US: (u64, u64) = (300_000, 2_000_000);
/// The other robot's babbling: head targets within these (yaw, pitch) radians of home.
pub const BABBLE_RAD: [f64; 2] = [0.08, 0.05];
/// It moves its head at this speed (rad/s, about the reach speed of Nao at 0.1) ...
pub const BABBLE_SPEED: f64 = 0.8;
/// ... and picks a new target after this many microseconds (uniform).
pub const BABBLE_DWELL_US: (u64, u64) = (300_000, 1_200_000);

/// One trial's scene state.
pub struct SceneState {
    /// Which scene the trial plays.
    pub scene: Scene,
    rng: ChaCha8Rng,
    /// Other: the other robot babbles (else it holds still at home).
    pub babbles: bool,
    other_head: [f64; 2],
    other_goal: [f64; 2],
    next_goal_us: u64,
    last_us: u64,
    /// Delayed: the delay, and the poses of the last `delay` (oldest first).
    pub delay_us: u64,
    history: VecDeque<(u64, BodyPose)>,
}

/// What the camera sees at one moment.
pub struct View {
    /// Head angles of the camera (our head, now).
    pub camera: [f64; 2],
    /// The body in view (our own in the mirror, delayed or not, or the other robot).
    pub seen: BodyPose,
    /// The picture is as it was at this time (now, or now minus the delay).
    pub as_of_us: u64,
}

impl SceneState {
    /// The scene at a trial's start, its draws (whether the other robot babbles, the delay)
    /// taken from `rng`, a stream of the trial's own.
    pub fn new(scene: Scene, mut rng: ChaCha8Rng) -> SceneState {
        let (babbles, delay_us) = match scene {
            Scene::Mirror => (false, 0),
            Scene::Other => (rng.gen_bool(0.5), 0),
            Scene::Delayed => (false, rng.gen_range(DELAY_RANGE_US.0..=DELAY_RANGE_US.1)),
        };
        SceneState {
            scene,
            rng,
            babbles,
            other_head: [0.0; 2],
            other_goal: [0.0; 2],
            next_goal_us: 0,
            last_us: 0,
            delay_us,
            history: VecDeque::new(),
        }
    }

    /// Advances to `now` with our body at `ours` (call every tick).
    pub fn step(&mut self, now: u64, ours: &BodyPose) {
        match self.scene {
            Scene::Mirror => {}
            Scene::Other => {
                if self.babbles {
                    if now >= self.next_goal_us {
                        self.other_goal = [
                            self.rng.gen_range(-BABBLE_RAD[0]..=BABBLE_RAD[0]),
                            self.rng.gen_range(-BABBLE_RAD[1]..=BABBLE_RAD[1]),
                        ];
                        self.next_goal_us = now + self.rng.gen_range(BABBLE_DWELL_US.0..=BABBLE_DWELL_US.1);
                    }
                    let step = BABBLE_SPEED * now.saturating_sub(self.last_us) as f64 * 1e-6;
                    for (h, g) in self.other_head.iter_mut().zip(self.other_goal) {
                        *h += (g - *h).clamp(-step, step);
                    }
                }
            }
            Scene::Delayed => {
                self.history.push_back((now, *ours));
                // Keep one pose at or before `now - delay`.
                while self.history.len() > 1 && self.history[1].0 + self.delay_us <= now {
                    self.history.pop_front();
                }
            }
        }
        self.last_us = now;
    }

    /// What the camera sees now, our body being at `ours`.
    pub fn view(&self, now: u64, ours: &BodyPose) -> View {
        let camera = [ours.head_yaw, ours.head_pitch];
        match self.scene {
            Scene::Mirror => View { camera, seen: *ours, as_of_us: now },
            Scene::Other => View {
                camera,
                seen: BodyPose::head(self.other_head[0], self.other_head[1]),
                as_of_us: now,
            },
            Scene::Delayed => {
                // Before the queue has filled the robot sat at home: the first pose.
                let pose = self.history.front().map_or(*ours, |h| h.1);
                let as_of = now.saturating_sub(self.delay_us);
                View { camera: [pose.head_yaw, pose.head_pitch], seen: pose, as_of_us: as_of }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn rng() -> ChaCha8Rng {
        let mut r = ChaCha8Rng::seed_from_u64(3);
        r.set_stream(2);
        r
    }

    #[test]
    fn the_delayed_view_is_the_pose_of_delay_ago() {
        let mut s = SceneState::new(Scene::Delayed, rng());
        assert!((DELAY_RANGE_US.0..=DELAY_RANGE_US.1).contains(&s.delay_us));
        let d = s.delay_us;
        for t in (0..=d + 500_000).step_by(1000) {
            let yaw = t as f64 * 1e-7;
            s.step(t, &BodyPose::head(yaw, 0.0));
            let v = s.view(t, &BodyPose::head(yaw, 0.0));
            // The newest pose on the 1 ms grid at or before `t - delay`.
            let want = (t.saturating_sub(d) / 1000 * 1000) as f64 * 1e-7;
            assert!((v.seen.head_yaw - want).abs() < 1e-12, "{t}: {} vs {want}", v.seen.head_yaw);
            // The camera turned with the head then, too: the frame is old as a whole.
            assert_eq!(v.camera[0], v.seen.head_yaw);
        }
    }

    #[test]
    fn the_other_robot_ignores_our_head() {
        let mut moved = false;
        for seed in 0..8 {
            let mut r = ChaCha8Rng::seed_from_u64(seed);
            r.set_stream(2);
            let mut s = SceneState::new(Scene::Other, r);
            let mut last = [0.0; 2];
            for t in (0..3_000_000).step_by(1000) {
                let ours = BodyPose::head(0.05 * (t as f64 * 1e-5).sin(), 0.0);
                s.step(t, &ours);
                let v = s.view(t, &ours);
                assert_eq!(v.camera, [ours.head_yaw, ours.head_pitch]);
                let h = [v.seen.head_yaw, v.seen.head_pitch];
                assert!(h[0].abs() <= BABBLE_RAD[0] && h[1].abs() <= BABBLE_RAD[1]);
                if !s.babbles {
                    assert_eq!(h, [0.0, 0.0]);
                }
                // At most the babbling speed.
                assert!((h[0] - last[0]).abs() <= BABBLE_SPEED * 1e-3 + 1e-12);
                moved |= h != last;
                last = h;
            }
        }
        assert!(moved, "some of 8 seeds babble");
    }
}
