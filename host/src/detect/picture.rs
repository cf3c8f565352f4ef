//! A detection drawn: the frame with its crop and mark, the observed and predicted face, the
//! saliency and the mask, and for a model with colour its colour saliency beside them.
use crate::detect::pipeline::Detection;
use image::GrayImage;

/// Frame with crop and detection | observed face over predicted face | saliency over mask |
/// colour saliency (a detection with one; `threshold`'s units are the grey saliency's, the
/// colour's are its own threshold's).
pub fn picture(frame: &GrayImage, face: &[u8], d: &Detection, threshold: f32) -> image::RgbImage {
    use image::Rgb;
    use imageproc::drawing::{draw_cross_mut, draw_hollow_rect_mut};
    use imageproc::rect::Rect;
    let (fw, fh) = frame.dimensions();
    let (w, h) = (d.crop.width, d.crop.height);
    let k = 2u32;
    let columns = if d.colour.is_some() { 3 } else { 2 };
    let mut img = image::RgbImage::from_pixel(
        fw + columns * (k * w + 4),
        fh.max(2 * k * h + 4),
        Rgb([32, 32, 32]),
    );
    for (x, y, p) in frame.enumerate_pixels() {
        img.put_pixel(x, y, Rgb([p[0]; 3]));
    }
    let red = Rgb([255, 40, 40]);
    let green = Rgb([40, 220, 40]);
    draw_hollow_rect_mut(
        &mut img,
        Rect::at(d.crop.x as i32, d.crop.y as i32).of_size(w, h),
        green,
    );
    if let Some(b) = d.blob {
        let [x0, y0, x1, y1] = b.box_xyxy;
        draw_hollow_rect_mut(
            &mut img,
            Rect::at(x0 as i32, y0 as i32).of_size(x1 - x0 + 1, y1 - y0 + 1),
            red,
        );
        draw_cross_mut(
            &mut img,
            Rgb([255, 255, 0]),
            b.centroid[0].round() as i32,
            b.centroid[1].round() as i32,
        );
    }
    let mut panel = |ox: u32, oy: u32, f: &dyn Fn(usize) -> Rgb<u8>| {
        for y in 0..h * k {
            for x in 0..w * k {
                let i = ((y / k) * w + x / k) as usize;
                img.put_pixel(ox + x, oy + y, f(i));
            }
        }
    };
    let x1 = fw + 4;
    let x2 = x1 + k * w + 4;
    let y2 = k * h + 4;
    panel(x1, 0, &|i| Rgb([face[i]; 3]));
    panel(x1, y2, &|i| {
        let g = (d.predicted[i] * 255.0).round().clamp(0.0, 255.0) as u8;
        Rgb([g; 3])
    });
    // Saliency: black at 0, white at the threshold, red above it.
    panel(x2, 0, &|i| {
        let s = d.saliency[i].max(0.0) / threshold;
        if s > 1.0 {
            Rgb([255, 0, 0])
        } else {
            Rgb([(s * 255.0) as u8; 3])
        }
    });
    panel(x2, y2, &|i| {
        if d.mask[i] {
            Rgb([255, 255, 255])
        } else {
            Rgb([0, 0, 0])
        }
    });
    // Colour saliency, the same scale against its own threshold (threshold units already).
    if let Some(c) = &d.colour {
        panel(x2 + k * w + 4, 0, &|i| {
            let s = c[i].max(0.0);
            if s > 1.0 {
                Rgb([255, 0, 0])
            } else {
                Rgb([(s * 255.0) as u8; 3])
            }
        });
    }
    img
}
