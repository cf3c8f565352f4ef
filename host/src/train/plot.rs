//! Loss curves as a PNG (linear axes) (plotters). Labels need a system font; without one the curves are drawn
//! bare rather than failing the training run.
use super::fit::History;
use anyhow::{anyhow, Result};
use plotters::prelude::*;
use std::path::Path;

/// Writes the train and test loss curves of `h` to `path` as an 800 x 500 PNG titled `title`.
pub fn loss_png(h: &History, title: &str, path: &Path) -> Result<()> {
    // Through a temporary file and a rename, as every output.
    crate::fsio::write_with(path, |tmp| match draw(h, title, tmp, true) {
        Ok(()) => Ok(()),
        Err(_) => draw(h, title, tmp, false),
    })
}

fn draw(h: &History, title: &str, path: &Path, text: bool) -> Result<()> {
    let e = |e: &dyn std::fmt::Display| anyhow!("loss plot {}: {e}", path.display());
    let all: Vec<f64> =
        h.train_loss.iter().chain(&h.test_loss).copied().filter(|v| v.is_finite() && *v > 0.0).collect();
    if all.is_empty() {
        return Err(anyhow!("no finite losses to plot"));
    }
    let hi = all.iter().copied().fold(0.0, f64::max) * 1.05;
    let n = h.train_loss.len().max(h.test_loss.len()).max(2);
    // Drawn into memory and written with `image`: plotters' own PNG encoder would compile a
    // second version of `image`.
    let (w, hgt) = (800u32, 500u32);
    let mut buf = vec![0u8; (w * hgt * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, hgt)).into_drawing_area();
        root.fill(&WHITE).map_err(|x| e(&x))?;
        let mut b = ChartBuilder::on(&root);
        b.margin(12);
        if text {
            b.caption(title, ("sans-serif", 30)).x_label_area_size(56).y_label_area_size(110);
        }
        let mut chart = b.build_cartesian_2d(1usize..n, 0.0..hi).map_err(|x| e(&x))?;
        if text {
            chart
                .configure_mesh()
                .x_desc("epoch")
                .y_desc("MSE (grey/255)")
                .y_label_formatter(&|v| format!("{v:.4}"))
                // Sized to stay readable at half a 1280 px page (the report shows two plots a row).
                .label_style(("sans-serif", 22))
                .axis_desc_style(("sans-serif", 24))
                .draw()
                .map_err(|x| e(&x))?;
        }
        let series = [(&h.train_loss, BLUE, "train"), (&h.test_loss, RED, "test")];
        for (v, colour, name) in series {
            let pts: Vec<(usize, f64)> =
                v.iter().enumerate().filter(|(_, y)| y.is_finite() && **y > 0.0).map(|(i, y)| (i + 1, *y)).collect();
            let s = chart.draw_series(LineSeries::new(pts, colour.stroke_width(2))).map_err(|x| e(&x))?;
            if text {
                s.label(name).legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour));
            }
        }
        if text {
            chart.configure_series_labels().label_font(("sans-serif", 22)).border_style(BLACK).background_style(WHITE).draw().map_err(|x| e(&x))?;
        }
        root.present().map_err(|x| e(&x))?;
    }
    let img = image::RgbImage::from_raw(w, hgt, buf).ok_or_else(|| anyhow!("loss plot: buffer size"))?;
    img.save(path).map_err(|x| e(&x))?;
    Ok(())
}
