use super::*;
use crate::marks::Mark;
use rand::SeedableRng;

fn clean(r: &Renderer, yaw: f64, pitch: f64, mark: Option<&Mark>) -> Rendered {
    r.render(&BodyPose::head(yaw, pitch), mark, &Variation::CLEAN)
}

fn centroid(mask: &GrayImage) -> [f64; 2] {
    let (mut sx, mut sy, mut n) = (0.0, 0.0, 0.0);
    for (x, y, p) in mask.enumerate_pixels() {
        if p.0[0] == 255 {
            sx += x as f64;
            sy += y as f64;
            n += 1.0;
        }
    }
    [sx / n, sy / n]
}

#[test]
fn mark_ground_truth_agrees_with_the_geometry() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for robot in Robot::ALL {
        let r = Renderer::new(robot);
        for i in 0..12 {
            let yaw = (i as f64 / 11.0 - 0.5) * 0.17;
            let pitch = ((i * 7 % 12) as f64 / 11.0 - 0.5) * 0.17;
            let mut mark = Mark::random(&mut rng);
            // A symmetric shape so that its pixel centroid is its centre's pixel.
            mark.shape = crate::marks::Shape::Rect { half_w: 0.006, half_h: 0.006 };
            let f = clean(&r, yaw, pitch, Some(&mark));
            let m = f.mark.expect("mark pixels");
            let n = m.mask.pixels().filter(|p| p.0[0] == 255).count() as u32;
            assert!(m.pixels > 20 && m.pixels == n, "{robot} {i}: {} vs {n}", m.pixels);
            let c = centroid(&m.mask);
            let p = body::project_head(&mark.point_head(), yaw, pitch).unwrap();
            assert!((c[0] - p[0]).abs() < 0.7 && (c[1] - p[1]).abs() < 0.7, "{robot} {i}: {c:?} vs {p:?}");
            // The inclusive box is the mask's extent.
            let [x0, y0, x1, y1] = m.box_xyxy;
            for (x, y, v) in m.mask.enumerate_pixels() {
                let inside = x >= x0 && x <= x1 && y >= y0 && y <= y1;
                assert!(v.0[0] == 0 || inside);
            }
            for (x, y) in [(x0, y0), (x1, y1)] {
                assert!(m.mask.rows().nth(y as usize).unwrap().any(|p| p.0[0] == 255), "row {y}");
                assert!((y0..=y1).any(|yy| m.mask.get_pixel(x, yy).0[0] == 255), "column {x}");
            }
            // Mark pixels carry the mark's colour (shaded): nearest to it of all palette colours.
            // Mark pixels carry the mark's colour, scaled by the light (plus a little gloss).
            let px = f.rgb.get_pixel(p[0].round() as u32, p[1].round() as u32).0.map(|v| v as f32);
            let c = mark.rgb.map(|v| v as f32 + 1.0);
            let k = (px[0] * c[0] + px[1] * c[1] + px[2] * c[2]) / (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
            let off = (0..3).map(|j| (px[j] - k * c[j]).abs()).fold(0.0, f32::max);
            assert!((0.3..1.3).contains(&k) && off < 20.0, "{robot} {i}: {px:?} for {:?}", mark.rgb);
        }
    }
}

#[test]
fn marks_stay_inside_the_face_crop() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let r = Renderer::new(Robot::Red);
    let a = 5f64.to_radians();
    for i in 0..40 {
        let (yaw, pitch) = ([-a, 0.0, a][i % 3], [a, -a, 0.0, a][i % 4]);
        let mark = Mark::random(&mut rng);
        let m = clean(&r, yaw, pitch, Some(&mark)).mark.unwrap();
        let [cx, cy] = body::crop_origin(yaw, pitch);
        let [x0, y0, x1, y1] = m.box_xyxy;
        assert!(m.pixels > 0);
        assert!(
            x0 >= cx && y0 >= cy && x1 < cx + body::CROP_W && y1 < cy + body::CROP_H,
            "{mark:?} box {:?} crop at {cx},{cy}",
            m.box_xyxy
        );
    }
}

#[test]
fn the_view_is_a_mirror() {
    // The robot's left eye (+y) shows on the left of the picture, as in a mirror; a camera
    // looking at another robot would see it on the right.
    let [l, r] = crate::looks::EYES.map(|[y, z]| {
        let p = body::face_point(y, z).unwrap();
        body::project_head(&p, 0.0, 0.0).unwrap()
    });
    assert!(l[0] < r[0] - 20.0, "{l:?} {r:?}");
    // Turning the head left turns the camera left: the reflection slides right. Looking down
    // slides it up.
    let c = Point3::from(Vector3::from(body::CROP_CENTRE_HEAD));
    let p0 = body::project_head(&c, 0.0, 0.0).unwrap();
    let py = body::project_head(&c, 0.08, 0.0).unwrap();
    let pp = body::project_head(&c, 0.0, 0.08).unwrap();
    assert!(py[0] > p0[0] + 10.0, "{p0:?} {py:?}");
    assert!(pp[1] < p0[1] - 10.0, "{p0:?} {pp:?}");
    // And the rendered face moves with it: the red cap's lowest row in the middle column.
    let ren = Renderer::new(Robot::Red);
    let f0 = clean(&ren, 0.0, 0.0, None).rgb;
    let f1 = clean(&ren, 0.0, 0.08, None).rgb;
    let cap_bottom = |f: &RgbImage| (0..HEIGHT).rev().find(|&y| {
        let p = f.get_pixel(160, y).0;
        p[0] > 120 && p[1] < 60 && y < 120
    });
    let (b0, b1) = (cap_bottom(&f0).unwrap(), cap_bottom(&f1).unwrap());
    assert!(b1 + 10 < b0, "cap at {b0}, looking down {b1}");
}

#[test]
fn the_face_fills_the_published_crop() {
    // The head (not background) spans about the crop's width, as in the real frames.
    for robot in Robot::ALL {
        let f = clean(&Renderer::new(robot), 0.0, 0.0, None).rgb;
        let bg = |x: u32| {
            let p = f.get_pixel(x, 110).0;
            let q = Renderer::new(robot).background[(110 * WIDTH + x) as usize].map(|c| (c * 255.0).round() as u8);
            p == q
        };
        let left = (0..WIDTH).find(|&x| !bg(x)).unwrap();
        let right = (0..WIDTH).rev().find(|&x| !bg(x)).unwrap();
        let w = right - left + 1;
        assert!((60..=78).contains(&w), "{robot}: head {w} px wide");
    }
}

#[test]
fn renders_are_deterministic_and_noise_has_the_right_sigma() {
    let r = Renderer::new(Robot::Skin);
    let pose = BodyPose::head(0.03, -0.02);
    let v = Variation { exposure: 0.97, eye_led: 0.6, noise_seed: Some(11), light: crate::light::Light::FIXED };
    let a = r.render(&pose, None, &v).rgb;
    assert_eq!(a, r.render(&pose, None, &v).rgb);
    let b = r.render(&pose, None, &Variation { noise_seed: Some(12), ..v }).rgb;
    assert_ne!(a, b);
    // Two noisy frames differ by noise of sigma sqrt(2) * 0.007 * 255 = 2.52 grey levels.
    let d: Vec<f64> = a.as_raw().iter().zip(b.as_raw()).map(|(x, y)| *x as f64 - *y as f64).collect();
    let mean = d.iter().sum::<f64>() / d.len() as f64;
    let sd = (d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (d.len() - 1) as f64).sqrt();
    assert!((sd - 2.52).abs() < 0.1 && mean.abs() < 0.05, "sd {sd} mean {mean}");
}

#[test]
fn leds_flicker_and_exposure_changes_brightness() {
    let r = Renderer::new(Robot::Red);
    let pose = BodyPose::head(0.0, 0.0);
    let dim = r.render(&pose, None, &Variation { eye_led: 0.55, ..Variation::CLEAN }).rgb;
    let bright = r.render(&pose, None, &Variation { eye_led: 1.0, ..Variation::CLEAN }).rgb;
    let [ey, ez] = crate::looks::EYES[0];
    let e = body::project_head(&body::face_point(ey + 0.005, ez).unwrap(), 0.0, 0.0).unwrap();
    let (x, y) = (e[0].round() as u32, e[1].round() as u32);
    let sum = |f: &RgbImage| f.get_pixel(x, y).0.iter().map(|v| *v as u32).sum::<u32>();
    assert!(sum(&bright) > sum(&dim) + 60, "{:?} {:?}", bright.get_pixel(x, y), dim.get_pixel(x, y));
    // Away from the eyes nothing changes.
    assert_eq!(bright.get_pixel(20, 20), dim.get_pixel(20, 20));
    let darker = r.render(&pose, None, &Variation { exposure: 0.98, ..Variation::CLEAN }).rgb;
    let mean = |f: &RgbImage| f.as_raw().iter().map(|v| *v as f64).sum::<f64>() / f.as_raw().len() as f64;
    let ratio = mean(&darker) / mean(&bright);
    assert!((ratio - 0.98).abs() < 0.005, "{ratio}");
}

#[test]
fn highlights_move_with_the_pose() {
    // The brightest head pixel (the specular spot) is not glued to the face texture: between
    // two head poses it moves by a different amount than the face does.
    let r = Renderer::new(Robot::Red);
    let spot = |yaw: f64| {
        let f = clean(&r, yaw, 0.0, None).rgb;
        let [x0, y0] = body::crop_origin(yaw, 0.0);
        let mut best = (0u32, 0u32, 0u32);
        for y in y0..y0 + body::CROP_H {
            for x in x0..x0 + body::CROP_W {
                let s = f.get_pixel(x, y).0.iter().map(|v| *v as u32).sum::<u32>();
                if s > best.0 {
                    best = (s, x - x0, y - y0);
                }
            }
        }
        (best.1 as i32, best.2 as i32)
    };
    let (a, b) = (spot(-0.3), spot(0.3));
    assert_ne!(a, b, "highlight stuck at the same place on the face");
}

/// OpenCV's TM_CCOEFF score of the template at (x, y).
fn ccoeff(img: &GrayImage, t: &GrayImage, x: u32, y: u32) -> f64 {
    let n = (t.width() * t.height()) as f64;
    let tm = t.pixels().map(|p| p.0[0] as f64).sum::<f64>() / n;
    let mut im = 0.0;
    for ty in 0..t.height() {
        for tx in 0..t.width() {
            im += img.get_pixel(x + tx, y + ty).0[0] as f64;
        }
    }
    im /= n;
    let mut s = 0.0;
    for ty in 0..t.height() {
        for tx in 0..t.width() {
            s += (t.get_pixel(tx, ty).0[0] as f64 - tm) * (img.get_pixel(x + tx, y + ty).0[0] as f64 - im);
        }
    }
    s
}

#[test]
fn template_matching_finds_the_face_crop() {
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let a = 5f64.to_radians();
    for robot in Robot::ALL {
        let r = Renderer::new(robot);
        let t = r.template();
        assert_eq!((t.width(), t.height()), (75, 58));
        for _ in 0..4 {
            let (yaw, pitch) = (rng.gen_range(-a..a), rng.gen_range(-a..a));
            let g = to_grey(&r.render(&BodyPose::head(yaw, pitch), None, &Variation::random(&mut rng)).rgb);
            let [ex, ey] = body::crop_origin(yaw, pitch);
            let mut best = (f64::MIN, 0, 0);
            for y in ey.saturating_sub(8)..=(ey + 8).min(HEIGHT - 58) {
                for x in ex.saturating_sub(8)..=(ex + 8).min(WIDTH - 75) {
                    let s = ccoeff(&g, &t, x, y);
                    if s > best.0 {
                        best = (s, x, y);
                    }
                }
            }
            let (dx, dy) = (best.1 as i32 - ex as i32, best.2 as i32 - ey as i32);
            // The face turns as well as moves, so the best match may sit a few pixels off the
            // projected crop; marks keep a margin of MARGIN_PX for that.
            let m = crate::marks::CROP_MARGIN_PX as i32;
            assert!(dx.abs() < m && dy.abs() < m, "{robot} ({yaw}, {pitch}): off by ({dx}, {dy})");
        }
    }
}

#[test]
fn the_arm_is_drawn_where_the_kinematics_put_it() {
    // Raise the left arm into a reach: the fingertip's mirror pixel turns from wall to arm.
    let r = Renderer::new(Robot::Red);
    let q = kin::ik_touch(&body::face_point(0.02, 0.06).unwrap()).unwrap();
    let tip = kin::fingertip(&q);
    let back = kin::arm_points(&kin::LeftArm::from_reach(&q), 1.0).wrist;
    let probe = nalgebra::center(&tip, &back);
    let mut pose = BodyPose::head(q[0], q[1]);
    let px = body::project_torso(&probe, q[0], q[1]).unwrap();
    let (x, y) = (px[0].round() as u32, px[1].round() as u32);
    let home = r.render(&pose, None, &Variation::CLEAN).rgb;
    pose.left_arm = kin::LeftArm::from_reach(&q);
    let reach = r.render(&pose, None, &Variation::CLEAN).rgb;
    assert_ne!(home.get_pixel(x, y), reach.get_pixel(x, y));
}

#[test]
fn a_mark_off_the_head_gets_a_point_on_its_edge() {
    let mut m = Mark::random(&mut ChaCha8Rng::seed_from_u64(1));
    for c in [[0.5, 0.06], [0.0, -1.0], [f64::NAN, 0.0], [0.0, 0.06]] {
        m.centre_yz = c;
        let p = m.point_head();
        let (cc, r) = crate::kin::HEAD_ELLIPSOID;
        let s = ((p.x - cc[0]) / r[0]).powi(2) + ((p.y - cc[1]) / r[1]).powi(2) + ((p.z - cc[2]) / r[2]).powi(2);
        assert!((s - 1.0).abs() < 1e-9 && p.x >= 0.0, "{c:?} -> {p:?}");
    }
}
