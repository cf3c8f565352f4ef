//! The robot's camera in a running world: renders what the head sees in the mirror at the
//! servos' current pose, cuts the face crop, and turns it into host-link messages
//! (`FrameStart` then `FrameChunk`s), as the PC does for a real board.
use crate::body;
use crate::light::{LightPlan, LightSchedule};
use crate::marks::Mark;
use crate::render::{to_grey, Rendered, Renderer, Variation};
use crate::world::World;
use crate::Robot;
use image::GrayImage;
use msr_shared::host_port::{FaceError, HostPort};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// One captured frame.
pub struct Capture {
    /// The rendered frame.
    pub frame: Rendered,
    /// Top-left of the face crop in the frame.
    pub crop_origin: [u32; 2],
    /// The grey face crop.
    pub crop: GrayImage,
    /// The head angles the frame was rendered at (true, not encoder readings).
    pub head: [f64; 2],
}

impl Capture {
    /// The face crop's wire bytes on the host link (`FrameStart` and its chunks), as the PC
    /// sends them: [`HostPort::encode_face`].
    pub fn wire(&self, port: &mut HostPort) -> Result<Vec<u8>, FaceError> {
        port.encode_face(self.crop_origin, [self.crop.width(), self.crop.height()], self.crop.as_raw())
    }
}

/// A camera with its own seeded nuisance (noise, LEDs, exposure) per frame.
pub struct Camera {
    renderer: Renderer,
    rng: ChaCha8Rng,
    /// The light over the run (fixed unless [`Camera::with_light`]).
    pub light: LightSchedule,
}

impl Camera {
    /// A camera on the world of `robot`, its noise drawn from `seed`.
    pub fn new(robot: Robot, seed: u64) -> Camera {
        let light = LightSchedule::new(LightPlan::Fixed, 1, &mut ChaCha8Rng::seed_from_u64(0));
        Camera { renderer: Renderer::new(robot), rng: ChaCha8Rng::seed_from_u64(seed), light }
    }

    /// This camera under `plan` over a run of `duration_us` (drawn from `seed`, apart from the
    /// camera's noise).
    pub fn with_light(mut self, plan: LightPlan, duration_us: u64, seed: u64) -> Camera {
        self.light = LightSchedule::new(plan, duration_us, &mut ChaCha8Rng::seed_from_u64(seed ^ 0x119E_7001));
        self
    }

    /// The renderer it draws frames with.
    pub fn renderer(&self) -> &Renderer {
        &self.renderer
    }

    /// Renders the world's current pose, with `mark` on the face if given. The crop is placed
    /// where the face is at the true head angles (what template matching finds, within a few
    /// pixels; see `marks::CROP_MARGIN_PX`).
    pub fn capture(&mut self, world: &World, mark: Option<&Mark>) -> Capture {
        let pose = world.body_pose();
        let var = Variation::random(&mut self.rng).lit(self.light.at(world.now_us));
        let frame = self.renderer.render(&pose, mark, &var);
        self.light.observed(&frame.rgb);
        let crop_origin = body::crop_origin(pose.head_yaw, pose.head_pitch);
        let crop = face_crop(&frame.rgb, crop_origin);
        Capture { frame, crop_origin, crop, head: [pose.head_yaw, pose.head_pitch] }
    }
}

impl Camera {
    /// As [`Camera::capture`], but only the face crop and a margin of 8 pixels are rendered
    /// (about 15 times faster); the rest of the frame is plain background.
    pub fn capture_face(&mut self, world: &World, mark: Option<&Mark>) -> Capture {
        let pose = world.body_pose();
        let var = Variation::random(&mut self.rng).lit(self.light.at(world.now_us));
        let crop_origin = body::crop_origin(pose.head_yaw, pose.head_pitch);
        let m = 8;
        let window = [
            crop_origin[0].saturating_sub(m),
            crop_origin[1].saturating_sub(m),
            body::CROP_W + 2 * m,
            body::CROP_H + 2 * m,
        ];
        let frame = self.renderer.render_window(&pose, mark, &var, window);
        self.light.observed(&frame.rgb);
        let crop = face_crop(&frame.rgb, crop_origin);
        Capture { frame, crop_origin, crop, head: [pose.head_yaw, pose.head_pitch] }
    }
}

/// The grey 75 x 58 crop at `origin` (clamped into the frame).
pub fn face_crop(rgb: &image::RgbImage, origin: [u32; 2]) -> GrayImage {
    let x = origin[0].min(rgb.width().saturating_sub(body::CROP_W));
    let y = origin[1].min(rgb.height().saturating_sub(body::CROP_H));
    let sub = image::imageops::crop_imm(rgb, x, y, body::CROP_W, body::CROP_H).to_image();
    to_grey(&sub)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::LinkEnd;
    use crate::world::{run, Flow, WorldConfig};
    use msr_shared::frame::{FrameAccumulator, MAX_WIRE_FRAME};
    use msr_shared::msg::{FrameHeader, HostToBoard};

    #[test]
    fn a_board_receives_the_crop_the_camera_took() {
        let mut cam = Camera::new(Robot::Skin, 1);
        let mut port = HostPort::default();
        let mut sent: Vec<GrayImage> = Vec::new();
        let mut acc = FrameAccumulator::<MAX_WIRE_FRAME>::new();
        let mut got: Vec<Vec<u8>> = Vec::new();
        let mut current: Option<(FrameHeader, Vec<u8>)> = None;
        // The board side: reassemble frames from the chunks.
        let mut fw = |_: u64, h: &mut LinkEnd, _: &mut LinkEnd| {
            for b in h.receive() {
                let Some(Ok(f)) = acc.push(b) else { continue };
                match f.message::<HostToBoard>() {
                    Ok(HostToBoard::FrameStart(hd)) => current = Some((hd, Vec::new())),
                    Ok(HostToBoard::FrameChunk { offset, data, .. }) => {
                        let (hd, buf) = current.as_mut().unwrap();
                        assert_eq!(offset as usize, buf.len());
                        buf.extend_from_slice(data);
                        if buf.len() == hd.width as usize * hd.height as usize {
                            got.push(current.take().unwrap().1);
                        }
                    }
                    _ => {}
                }
            }
        };
        let mark = Mark::random(&mut ChaCha8Rng::seed_from_u64(2));
        let (_, report) = run(
            &WorldConfig::default(),
            &mut fw,
            |w: &mut World| {
                // 10 frames a second.
                if w.now_us.is_multiple_of(100_000) && sent.len() < 5 {
                    let c = cam.capture(w, Some(&mark));
                    assert_eq!(c.crop_origin, body::crop_origin(0.0, 0.0));
                    assert!(c.frame.mark.as_ref().unwrap().pixels > 0);
                    w.host.send(&c.wire(&mut port).unwrap());
                    sent.push(c.crop);
                }
                if w.now_us >= 600_000 { Flow::Stop } else { Flow::Continue }
            },
            1_000_000,
        )
        .unwrap();
        assert_eq!(got.len(), 5);
        for (g, s) in got.iter().zip(&sent) {
            assert_eq!(g, s.as_raw());
        }
        // Frames differ (noise), but only a little.
        assert_ne!(sent[0], sent[1]);
        assert!(report.end_us == 600_000);
    }

    #[test]
    fn the_face_only_capture_has_the_same_crop() {
        let mut idle = |_: u64, _: &mut LinkEnd, _: &mut LinkEnd| {};
        let mark = Mark::random(&mut ChaCha8Rng::seed_from_u64(5));
        let mut checked = false;
        run(&WorldConfig::default(), &mut idle, |w: &mut World| {
            let full = Camera::new(Robot::Red, 9).capture(w, Some(&mark));
            let face = Camera::new(Robot::Red, 9).capture_face(w, Some(&mark));
            // Same pixels in the crop (noise is drawn in scan order, so compare without it).
            let (fm, cm) = (full.frame.mark.unwrap(), face.frame.mark.unwrap());
            assert_eq!((fm.pixels, fm.box_xyxy), (cm.pixels, cm.box_xyxy));
            let diff = full.crop.as_raw().iter().zip(face.crop.as_raw()).map(|(a, b)| (*a as i32 - *b as i32).abs()).max();
            assert!(diff.unwrap() <= 12, "{diff:?}");
            checked = true;
            Flow::Stop
        }, 10_000).unwrap();
        assert!(checked);
    }

    #[test]
    fn crops_are_clamped_into_the_frame() {
        let img = image::RgbImage::new(320, 240);
        let c = face_crop(&img, [300, 230]);
        assert_eq!(c.dimensions(), (75, 58));
        // (Crops the frame messages cannot carry: `msr_shared::host_port`'s tests.)
    }
}
