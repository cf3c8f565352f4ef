//! Marks stuck on the face: a shape and a colour, placed at a head-frame (y, z) and pressed onto
//! the head along the head's x axis (a decal), so they move with the head.
//!
//! Sizes are given in pixels as seen at head (0, 0) and converted to metres with the camera's
//! scale at the face, so the paper's mark is 14 x 14 pixels in the frame.
use crate::body;
use nalgebra::Point3;
use rand::Rng;

#[derive(Clone, Copy, Debug, PartialEq)]
/// A mark's outline.
pub enum Shape {
    /// Axis-aligned rectangle, half sizes (y, z) in metres.
    /// A rectangle of these half sizes, metres.
    Rect {
        /// Half the width, metres.
        half_w: f64,
        /// Half the height, metres.
        half_h: f64,
    },
    /// Regular hexagon with two vertices on the y axis; circumradius in metres.
    /// A regular hexagon of this circumradius, metres.
    Hexagon {
        /// Circumradius, metres.
        radius: f64,
    },
}

/// One mark.
#[derive(Clone, Debug, PartialEq)]
pub struct Mark {
    /// "rectangle", "hexagon", "postit", "vbar" or "hbar".
    pub kind: &'static str,
    /// Colour name.
    pub colour: &'static str,
    /// Colour, RGB.
    pub rgb: [u8; 3],
    /// Outline.
    pub shape: Shape,
    /// Centre in the head frame (y, z).
    pub centre_yz: [f64; 2],
}

/// The paper's rectangle and bar colours.
pub const COLOURS: [(&str, [u8; 3]); 12] = [
    ("red", [215, 35, 40]),
    ("green", [40, 190, 70]),
    ("blue", [35, 75, 215]),
    ("yellow", [240, 215, 40]),
    ("pink", [245, 115, 185]),
    ("orange", [245, 135, 30]),
    ("cyan", [40, 195, 215]),
    ("purple", [125, 45, 165]),
    ("black", [25, 25, 25]),
    ("grey226", [226, 226, 226]),
    ("grey185", [185, 185, 185]),
    ("grey149", [149, 149, 149]),
];

/// Post-it colours.
pub const POSTIT_COLOURS: [(&str, [u8; 3]); 5] = [
    ("yellow", [250, 235, 105]),
    ("pink", [250, 120, 180]),
    ("green", [140, 225, 90]),
    ("orange", [250, 160, 60]),
    ("blue", [95, 185, 240]),
];

/// Mark kinds with sizes in pixels (width, height) at head (0, 0).
pub const KINDS: [&str; 5] = ["rectangle", "hexagon", "postit", "vbar", "hbar"];
const POSTIT_SIZES_PX: [[f64; 2]; 3] = [[13.0, 13.0], [18.0, 18.0], [18.0, 24.0]];
const RECT_PX: f64 = 14.0;
const HEX_RADIUS_PX: f64 = 9.0;
const BAR_PX: [f64; 2] = [6.0, 26.0];

/// Marks keep this many pixels from the edge of the face crop, so that a template match a few
/// pixels off (the face turns as well as moves) still holds the whole mark.
pub const CROP_MARGIN_PX: f64 = 4.0;

/// Metres per pixel at the face centre, at head (0, 0).
pub fn metres_per_pixel() -> f64 {
    let a = body::face_point(-0.01, 0.06).expect("face");
    let b = body::face_point(0.01, 0.06).expect("face");
    let pa = body::project_head(&a, 0.0, 0.0).expect("visible");
    let pb = body::project_head(&b, 0.0, 0.0).expect("visible");
    0.02 / (pa[0] - pb[0]).abs()
}

impl Mark {
    /// Whether a head-frame point on the head surface carries the mark.
    #[inline]
    pub fn covers(&self, h: &Point3<f64>) -> bool {
        if h.x <= 0.0 {
            return false;
        }
        let s = (h.y - self.centre_yz[0]).abs();
        let t = (h.z - self.centre_yz[1]).abs();
        match self.shape {
            Shape::Rect { half_w, half_h } => s <= half_w && t <= half_h,
            Shape::Hexagon { radius } => {
                let r3 = 3f64.sqrt();
                t <= radius * r3 / 2.0 && r3 * s + t <= r3 * radius
            }
        }
    }

    /// Half extents in (y, z), metres.
    pub fn half_extent(&self) -> [f64; 2] {
        match self.shape {
            Shape::Rect { half_w, half_h } => [half_w, half_h],
            Shape::Hexagon { radius } => [radius, radius * 3f64.sqrt() / 2.0],
        }
    }

    /// The mark's centre on the head surface (head frame). A centre given off the head's
    /// outline is moved onto its edge.
    pub fn point_head(&self) -> Point3<f64> {
        let [y, z] = self.centre_yz;
        if let Some(p) = body::face_point(y, z) {
            return p;
        }
        let (c, r) = crate::kin::HEAD_ELLIPSOID;
        let (u, v) = ((y - c[1]) / r[1], (z - c[2]) / r[2]);
        let k = 0.999 / (u * u + v * v).sqrt().max(1e-12);
        let (u, v) = if (u * k).is_finite() && (v * k).is_finite() { (u * k, v * k) } else { (0.0, 0.0) };
        body::face_point(c[1] + u * r[1], c[2] + v * r[2]).expect("inside the outline")
    }

    /// A mark of `kind` with random size (post-its) and colour, centred at `centre_yz`.
    pub fn of_kind<R: Rng>(kind: &str, centre_yz: [f64; 2], rng: &mut R) -> Option<Mark> {
        let m = metres_per_pixel();
        let rect = |w: f64, h: f64| Shape::Rect { half_w: w * m / 2.0, half_h: h * m / 2.0 };
        let (kind, shape, palette): (&'static str, Shape, &[(&'static str, [u8; 3])]) = match kind {
            "rectangle" => ("rectangle", rect(RECT_PX, RECT_PX), &COLOURS),
            "hexagon" => ("hexagon", Shape::Hexagon { radius: HEX_RADIUS_PX * m }, &COLOURS),
            "postit" => {
                let [w, h] = POSTIT_SIZES_PX[rng.gen_range(0..POSTIT_SIZES_PX.len())];
                ("postit", rect(w, h), &POSTIT_COLOURS)
            }
            "vbar" => ("vbar", rect(BAR_PX[0], BAR_PX[1]), &COLOURS),
            "hbar" => ("hbar", rect(BAR_PX[1], BAR_PX[0]), &COLOURS),
            _ => return None,
        };
        let (colour, rgb) = palette[rng.gen_range(0..palette.len())];
        Some(Mark { kind, colour, rgb, shape, centre_yz })
    }

    /// A random mark: kind, size and colour at random, centre uniform over the part of the
    /// mark area ([`body::FACE_Y`] x [`body::FACE_Z`]) where the whole mark stays inside the
    /// face crop at head (0, 0).
    pub fn random<R: Rng>(rng: &mut R) -> Mark {
        let kind = KINDS[rng.gen_range(0..KINDS.len())];
        Mark::random_of_kind(kind, rng).expect("known kind")
    }

    /// As [`Mark::random`] for one kind; `None` for an unknown kind.
    pub fn random_of_kind<R: Rng>(kind: &str, rng: &mut R) -> Option<Mark> {
        let mut mark = Mark::of_kind(kind, [0.0, 0.06], rng)?;
        for _ in 0..1000 {
            let c = [rng.gen_range(body::FACE_Y[0]..=body::FACE_Y[1]), rng.gen_range(body::FACE_Z[0]..=body::FACE_Z[1])];
            mark.centre_yz = c;
            if mark.fits_crop() {
                return Some(mark);
            }
        }
        // The centre of the area always fits; reaching here would be a geometry bug.
        mark.centre_yz = [0.0, 0.06];
        Some(mark)
    }

    /// Whether the mark's corners lie on the head and inside the face crop at head (0, 0),
    /// [`CROP_MARGIN_PX`] in from the edge.
    pub fn fits_crop(&self) -> bool {
        let [hw, hh] = self.half_extent();
        let [x0, y0] = body::crop_origin(0.0, 0.0).map(f64::from);
        let (x1, y1) = (x0 + body::CROP_W as f64 - 1.0, y0 + body::CROP_H as f64 - 1.0);
        [(-hw, -hh), (hw, -hh), (-hw, hh), (hw, hh)].iter().all(|(dy, dz)| {
            let Some(p) = body::face_point(self.centre_yz[0] + dy, self.centre_yz[1] + dz) else {
                return false;
            };
            matches!(body::project_head(&p, 0.0, 0.0),
                Some([u, v]) if u >= x0 + CROP_MARGIN_PX && u <= x1 - CROP_MARGIN_PX && v >= y0 + CROP_MARGIN_PX && v <= y1 - CROP_MARGIN_PX)
        })
    }
}
