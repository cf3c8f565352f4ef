//! Ray-cast mirror-view frames: the camera ray is reflected at the mirror plane and meets the
//! body's ellipsoids; the nearest hit is coloured by the robot's look, lit by one key light with
//! a Blinn-Phong highlight (so highlights move with the pose), then exposure and camera noise are
//! applied. Marks are decals on the head surface, so they move with the head, and the pixels that
//! show them are the exact mask.
use crate::body::{self, BodyPose, Ellipsoid, Part, HEIGHT, WIDTH};
use crate::kin;
use crate::looks::{self, Robot};
use crate::light::Light;
use crate::marks::Mark;
use image::{GrayImage, RgbImage};
use nalgebra::{Point3, Vector3};
use rand::{Rng, RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Camera noise: sigma as a fraction of full scale (the Gazebo mirror camera's).
pub const NOISE_SIGMA: f32 = 0.007;

/// Per-frame nuisance: what changes between two frames at the same pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Variation {
    /// Exposure gain, around 1.
    pub exposure: f32,
    /// Eye-LED brightness, 0..1.
    pub eye_led: f32,
    /// Seed of the camera noise; `None` renders without noise.
    pub noise_seed: Option<u64>,
    /// The room's light and the camera's exposure and white balance ([`Light::FIXED`]: the
    /// calibrated light).
    pub light: Light,
}

impl Variation {
    /// No noise, nominal exposure and LEDs: for templates and tests.
    pub const CLEAN: Variation = Variation { exposure: 1.0, eye_led: 0.8, noise_seed: None, light: Light::FIXED };

    /// Normal variation: exposure within about +-2 %, flickering LEDs, fresh noise.
    pub fn random<R: Rng>(rng: &mut R) -> Variation {
        Variation {
            exposure: 1.0 + rng.gen_range(-0.02..0.02),
            eye_led: rng.gen_range(0.55..1.0),
            noise_seed: Some(rng.next_u64()),
            light: Light::FIXED,
        }
    }

    /// This variation under `light`.
    pub fn lit(self, light: Light) -> Variation {
        Variation { light, ..self }
    }
}

/// One rendered frame and, when a mark was drawn, its ground truth in pixels.
pub struct Rendered {
    /// The frame, RGB.
    pub rgb: RgbImage,
    /// Where the mark was drawn, if there was one.
    pub mark: Option<MarkPixels>,
}

/// Where a mark shows in a frame.
#[derive(Clone, Debug, PartialEq)]
pub struct MarkPixels {
    /// Full-frame mask, 255 on mark pixels.
    pub mask: GrayImage,
    /// Number of mark pixels.
    pub pixels: u32,
    /// Inclusive [x0, y0, x1, y1]; all zero when no pixel shows.
    pub box_xyxy: [u32; 4],
    /// Mean absolute grey difference the mark makes on its pixels (before noise), 0..255.
    pub contrast: f32,
}

/// Renders frames of one robot. Holds per-pixel tables so that each frame only casts rays.
pub struct Renderer {
    robot: Robot,
    /// Camera-frame ray direction per pixel (unnormalised; x = 1).
    rays: Vec<[f64; 2]>,
    background: Vec<[f32; 3]>,
    /// Standard normal samples, indexed by random 16-bit numbers.
    normal_table: Vec<f32>,
}

impl Renderer {
    /// A renderer of `robot`.
    pub fn new(robot: Robot) -> Renderer {
        let mut rays = Vec::with_capacity((WIDTH * HEIGHT) as usize);
        let mut background = Vec::with_capacity(rays.capacity());
        for y in 0..HEIGHT {
            for x in 0..WIDTH {
                rays.push([(body::CX - x as f64) / body::FOCAL_PX, (body::CY - y as f64) / body::FOCAL_PX]);
                background.push(looks::background(x as f32 / WIDTH as f32, y as f32 / HEIGHT as f32));
            }
        }
        // Quantiles of the standard normal: deterministic and exact in distribution up to 1/65536.
        let normal_table = (0..65536)
            .map(|i| inverse_normal_cdf((i as f64 + 0.5) / 65536.0) as f32)
            .collect();
        Renderer { robot, rays, background, normal_table }
    }

    /// The robot it draws.
    pub fn robot(&self) -> Robot {
        self.robot
    }

    /// Renders the mirror view at `pose`, with an optional mark on the face.
    pub fn render(&self, pose: &BodyPose, mark: Option<&Mark>, var: &Variation) -> Rendered {
        self.render_window(pose, mark, var, [0, 0, WIDTH, HEIGHT])
    }

    /// As [`Renderer::render`], but casts rays only inside `window` ([x, y, width, height]);
    /// outside it the frame is plain background without noise, and the mark's mask and counts
    /// cover the window only. For episodes that only look at the face crop.
    pub fn render_window(&self, pose: &BodyPose, mark: Option<&Mark>, var: &Variation, window: [u32; 4]) -> Rendered {
        self.render_seen([pose.head_yaw, pose.head_pitch], pose, mark, var, window)
    }

    /// As [`Renderer::render_window`], with the camera at head angles `camera` (yaw, pitch) and
    /// the body in view at `pose`: a second robot of the same look standing where the mirror
    /// image would be (the mirror image of a left-right symmetric body is such a body), moving
    /// on its own. With `camera` equal to `pose`'s head it is the mirror.
    pub fn render_seen(&self, camera: [f64; 2], pose: &BodyPose, mark: Option<&Mark>, var: &Variation, window: [u32; 4]) -> Rendered {
        let (wx0, wy0) = (window[0], window[1]);
        let (wx1, wy1) = (window[0].saturating_add(window[2]), window[1].saturating_add(window[3]));
        let prims = body::ellipsoids(pose);
        let boxes: Vec<[i32; 4]> = prims.iter().map(|e| screen_box(e, camera)).collect();
        let cam = kin::camera_pose(camera[0], camera[1]);
        let rot = cam.rotation.to_rotation_matrix();
        let origin = Point3::from(cam.translation.vector);
        let inv_frames: Vec<_> = prims.iter().map(|e| e.frame.inverse()).collect();
        let head_inv = inv_frames[0];
        let lit = var.light;
        let fixed = lit == Light::FIXED;
        let light = if fixed { looks::LIGHT.normalize() } else { lit.key_dir().normalize() };
        let room = lit.room();
        let look = looks::Look::of(self.robot, var.eye_led);

        let mut rgb = RgbImage::new(WIDTH, HEIGHT);
        let mut mask = mark.map(|_| GrayImage::new(WIDTH, HEIGHT));
        let (mut mark_n, mut mark_diff) = (0u32, 0f32);
        let mut bbox = [u32::MAX, u32::MAX, 0, 0];
        let mut noise = var.noise_seed.map(ChaCha8Rng::seed_from_u64);
        let mut noise_bits = 0u64;
        let mut noise_left = 0;
        let gain = var.exposure * 255.0;
        // Per channel; exactly `gain` under the fixed light (x 1.0).
        let gains = [0, 1, 2].map(|c| gain * (lit.exposure * lit.tint[c]));
        let bg_out = [0, 1, 2].map(|c| lit.exposure * lit.tint[c] * room);

        // Per row: the primitives whose screen box spans it, and the columns they cover.
        let mut row_prims: Vec<usize> = Vec::with_capacity(prims.len());
        let mut row_span = (i32::MAX, i32::MIN);
        let mut row = u32::MAX;
        for (i, px) in rgb.pixels_mut().enumerate() {
            let (x, y) = ((i as u32) % WIDTH, (i as u32) / WIDTH);
            if x < wx0 || x >= wx1 || y < wy0 || y >= wy1 {
                *px = if fixed {
                    image::Rgb(self.background[i].map(|c| (c * 255.0).round() as u8))
                } else {
                    let b = self.background[i];
                    image::Rgb([0, 1, 2].map(|c| (b[c] * bg_out[c] * 255.0).round().clamp(0.0, 255.0) as u8))
                };
                continue;
            }
            if y != row {
                row = y;
                row_prims.clear();
                row_span = (i32::MAX, i32::MIN);
                for (k, b) in boxes.iter().enumerate() {
                    if (y as i32) >= b[1] && (y as i32) <= b[3] {
                        row_prims.push(k);
                        row_span = (row_span.0.min(b[0]), row_span.1.max(b[2]));
                    }
                }
            }
            let mut colour = self.background[i];
            if !fixed {
                colour = colour.map(|c| c * room);
            }
            let xi = x as i32;
            let r = self.rays[i];
            let d = if xi >= row_span.0 && xi <= row_span.1 {
                rot * Vector3::new(1.0, r[0], r[1])
            } else {
                Vector3::zeros()
            };
            if d.x > 1e-9 {
                // Reflect at the mirror plane.
                let t = (body::MIRROR_X - origin.x) / d.x;
                let o = origin + d * t;
                let d = Vector3::new(-d.x, d.y, d.z);
                let mut near: Option<(f64, usize)> = None;
                for &k in &row_prims {
                    let b = boxes[k];
                    if xi < b[0] || xi > b[2] {
                        continue;
                    }
                    if let Some(t) = prims[k].hit(&o, &d) {
                        if near.is_none_or(|n| t < n.0) {
                            near = Some((t, k));
                        }
                    }
                }
                if let Some((t, k)) = near {
                    let e = &prims[k];
                    let p = o + d * t;
                    let n = e.normal(&p);
                    let view = -d.normalize();
                    let local = inv_frames[k] * p;
                    let mut surf = look.surface(e.part, &local);
                    let mut on_mark = false;
                    if let (Part::Head, Some(m)) = (e.part, mark) {
                        let h = head_inv * p;
                        if m.covers(&h) {
                            on_mark = true;
                            let plain = shade(&surf, &n, &light, &view, &lit);
                            surf = looks::Surface::paint(m.rgb);
                            let marked = shade(&surf, &n, &light, &view, &lit);
                            mark_diff += (grey_f(marked) - grey_f(plain)).abs() * 255.0;
                        }
                    }
                    colour = shade(&surf, &n, &light, &view, &lit);
                    if on_mark {
                        mark_n += 1;
                        bbox = [bbox[0].min(x), bbox[1].min(y), bbox[2].max(x), bbox[3].max(y)];
                        if let Some(mk) = mask.as_mut() {
                            mk.put_pixel(x, y, image::Luma([255]));
                        }
                    }
                }
            }
            for ((c, out), g) in colour.iter().zip(px.0.iter_mut()).zip(gains) {
                let mut v = c * g;
                if let Some(rng) = noise.as_mut() {
                    if noise_left == 0 {
                        noise_bits = rng.next_u64();
                        noise_left = 4;
                    }
                    let idx = (noise_bits & 0xFFFF) as usize;
                    noise_bits >>= 16;
                    noise_left -= 1;
                    v += self.normal_table[idx] * NOISE_SIGMA * 255.0;
                }
                *out = v.round().clamp(0.0, 255.0) as u8;
            }
        }
        let mark = mask.map(|mask| MarkPixels {
            mask,
            pixels: mark_n,
            box_xyxy: if mark_n == 0 { [0; 4] } else { bbox },
            contrast: if mark_n == 0 { 0.0 } else { mark_diff / mark_n as f32 },
        });
        Rendered { rgb, mark }
    }

    /// The robot's face template: a clean frame at head (0, 0), the 75 x 58 crop around the face,
    /// in grey.
    pub fn template(&self) -> GrayImage {
        let f = self.render(&BodyPose::head(0.0, 0.0), None, &Variation::CLEAN);
        let [x0, y0] = body::crop_origin(0.0, 0.0);
        let g = to_grey(&f.rgb);
        image::imageops::crop_imm(&g, x0, y0, body::CROP_W, body::CROP_H).to_image()
    }
}

/// Blinn-Phong under `lit`'s ambient share and key strength (x 1.0 and the same order of
/// operations under the fixed light, so its frames keep their bytes).
fn shade(s: &looks::Surface, n: &Vector3<f64>, l: &Vector3<f64>, v: &Vector3<f64>, lit: &Light) -> [f32; 3] {
    let diffuse = n.dot(l).max(0.0) as f32;
    let h = (l + v).normalize();
    let spec = (n.dot(&h).max(0.0) as f32).powi(s.shininess) * s.specular * lit.key;
    let k = lit.ambient + (1.0 - lit.ambient) * diffuse * lit.key;
    [0, 1, 2].map(|c| s.albedo[c] * k + spec + s.emission[c])
}

fn grey_f(c: [f32; 3]) -> f32 {
    0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2]
}

/// RGB to grey with OpenCV's `cvtColor(RGB2GRAY)` fixed-point weights.
pub fn to_grey(rgb: &RgbImage) -> GrayImage {
    let mut g = GrayImage::new(rgb.width(), rgb.height());
    for (o, p) in g.pixels_mut().zip(rgb.pixels()) {
        let [r, gg, b] = p.0.map(u32::from);
        o.0[0] = ((r * 4899 + gg * 9617 + b * 1868 + 8192) >> 14) as u8;
    }
    g
}

/// Pixel box that contains an ellipsoid's mirror image, from its bounding-box corners.
fn screen_box(e: &Ellipsoid, camera: [f64; 2]) -> [i32; 4] {
    let mut b = [i32::MAX, i32::MAX, i32::MIN, i32::MIN];
    for c in e.corners() {
        match body::project_torso(&c, camera[0], camera[1]) {
            Some([u, v]) => {
                b = [
                    b[0].min(u.floor() as i32 - 1),
                    b[1].min(v.floor() as i32 - 1),
                    b[2].max(u.ceil() as i32 + 1),
                    b[3].max(v.ceil() as i32 + 1),
                ];
            }
            None => return [i32::MIN, i32::MIN, i32::MAX, i32::MAX],
        }
    }
    b
}

/// Acklam's rational approximation of the standard normal quantile (relative error < 1.2e-9).
#[allow(clippy::excessive_precision)] // the published coefficients, as published
fn inverse_normal_cdf(p: f64) -> f64 {
    const A: [f64; 6] = [-3.969683028665376e1, 2.209460984245205e2, -2.759285104469687e2, 1.383577518672690e2, -3.066479806614716e1, 2.506628277459239];
    const B: [f64; 5] = [-5.447609879822406e1, 1.615858368580409e2, -1.556989798598866e2, 6.680131188771972e1, -1.328068155288572e1];
    const C: [f64; 6] = [-7.784894002430293e-3, -3.223964580411365e-1, -2.400758277161838, -2.549732539343734, 4.374664141464968, 2.938163982698783];
    const D: [f64; 4] = [7.784695709041462e-3, 3.224671290700398e-1, 2.445134137142996, 3.754408661907416];
    let tail = |q: f64| (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5]) / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0);
    if p < 0.02425 {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - 0.02425 {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

#[cfg(test)]
mod tests;
