//! What a detection says: as JSON, as one readable line, and why a frame detected nothing.
use crate::data::crop::CropBox;
use crate::detect::pipeline::{Detection, JOINTS};

/// One detection as JSON (full-frame pixels, inclusive boxes), keys in the documented order.
pub fn to_json(d: &Detection) -> String {
    #[derive(serde::Serialize)]
    struct Out {
        crop: CropBox,
        blob: Option<crate::detect::pipeline::Blob>,
        joints: Option<Joints>,
        /// Why nothing can be detected in this frame: "NoFace", "SceneChanged", or null.
        reason: Option<&'static str>,
        /// The photometric fit: the prediction's grey per observed grey, and the offset.
        light: Light,
        /// What the frame's own error spreads, and the floor its sigmas were widened by
        /// (`msr_firmware::floor`), grey levels.
        camera: Camera,
    }
    #[derive(serde::Serialize)]
    struct Camera {
        spread: f32,
        floor: f32,
    }
    #[derive(serde::Serialize)]
    struct Light {
        gain: f32,
        offset: f32,
        correlation: f32,
        samples: u16,
        inliers: u16,
        /// The grey levels where the camera clipped, darkest and brightest: 0 and 255, or a
        /// plateau's (`msr_firmware::light::PLATEAU_SHARE`).
        clip: [u8; 2],
    }
    #[derive(serde::Serialize)]
    #[allow(non_snake_case)]
    struct Joints {
        HeadYaw: f32,
        HeadPitch: f32,
        LShoulderPitch: f32,
        LShoulderRoll: f32,
        LElbowRoll: f32,
    }
    let out = Out {
        crop: d.crop,
        blob: d.blob,
        joints: d.joints.map(|j| Joints {
            HeadYaw: j[0],
            HeadPitch: j[1],
            LShoulderPitch: j[2],
            LShoulderRoll: j[3],
            LElbowRoll: j[4],
        }),
        reason: reason(d),
        light: Light {
            gain: d.light.gain_f32(),
            offset: d.light.offset_grey(),
            correlation: d.light.correlation_milli as f32 / 1000.0,
            samples: d.light.samples,
            inliers: d.light.inliers,
            clip: d.light.clip,
        },
        camera: Camera { spread: d.spread[0], floor: d.spread[1] },
    };
    // Plain structs and finite floats: serialising cannot fail.
    serde_json::to_string(&out).unwrap_or_default()
}

/// Why a frame yields no detection whatever it shows: `NoFace` (the crop does not follow the
/// predicted face: black, white, covered, someone else), `SceneChanged` (a light the fit cannot
/// explain, or one that changed while the frame was taken); `None` when the face was seen.
pub fn reason(d: &Detection) -> Option<&'static str> {
    use crate::detect::pipeline::Verdict;
    match d.light.verdict {
        Verdict::Face => None,
        Verdict::NoFace => Some("NoFace"),
        Verdict::SceneChanged => Some("SceneChanged"),
    }
}

/// One detection as a readable line: the face crop and the mark (area, box, centroid, the reach's
/// joint angles in radians), or why the frame detected nothing.
pub fn readable(d: &Detection) -> String {
    let c = d.crop;
    if let Some(r) = reason(d) {
        return format!(
            "no detection: {r} (crop at ({}, {}); light fit gain {:.2}, offset {:.1}, correlation {:.2})",
            c.x,
            c.y,
            d.light.gain_f32(),
            d.light.offset_grey(),
            d.light.correlation_milli as f32 / 1000.0
        );
    }
    let mut s = format!("face at ({}, {}) {}x{}: ", c.x, c.y, c.width, c.height);
    match d.blob {
        None => s += "no mark",
        Some(b) => {
            s += &format!(
                "mark of {} px, box {:?}, centroid ({:.1}, {:.1})",
                b.area, b.box_xyxy, b.centroid[0], b.centroid[1]
            );
            if let Some(j) = d.joints {
                let parts: Vec<String> = JOINTS
                    .iter()
                    .zip(j)
                    .map(|(n, v)| format!("{n} {v:.3}"))
                    .collect();
                s += &format!("; reach: {}", parts.join(", "));
            }
        }
    }
    if d.spread[1] > 0.0 {
        s += &format!(" (camera: sigma widened by {:.1} grey levels, the frame spreads {:.1})", d.spread[1], d.spread[0]);
    }
    s
}
