//! `msr template`: cut a face template out of a camera frame (the box is inclusive, in
//! full-frame pixels, as the datasets' mark boxes).
use crate::data::crop;
use crate::fsio;
use anyhow::{bail, Result};
use std::path::PathBuf;

/// `msr template`'s flags: the frame, the face's box and the output.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// A camera frame (any image; taken as grey)
    #[arg(long)]
    pub frame: PathBuf,
    /// The face's box: x0,y0,x1,y1, inclusive
    #[arg(long, value_name = "x0,y0,x1,y1", allow_hyphen_values = true, value_parser = box_arg)]
    pub r#box: [u32; 4],
    /// The template to write (PNG), e.g. DIR/template.png for `msr record --out DIR`
    #[arg(long)]
    pub out: PathBuf,
}

/// `x0,y0,x1,y1` (inclusive) as numbers, checked for order.
pub fn parse_box(s: &str) -> Result<[u32; 4]> {
    let v: Vec<u32> = s
        .split(',')
        .map(|p| p.trim().parse::<u32>())
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow::anyhow!("x0,y0,x1,y1 in whole pixels (0 or more) are needed"))?;
    let [x0, y0, x1, y1] = v[..] else {
        bail!("four numbers x0,y0,x1,y1 are needed, got {}", v.len())
    };
    if x1 < x0 || y1 < y0 {
        bail!("x1 must not be left of x0, nor y1 above y0");
    }
    Ok([x0, y0, x1, y1])
}

/// [`parse_box`] for the parser: a box that does not parse is a usage error (exit 2).
fn box_arg(s: &str) -> Result<[u32; 4], String> {
    parse_box(s).map_err(|e| e.to_string())
}

/// Cuts the box out of the frame and writes it as a PNG.
pub fn run(a: Args) -> Result<()> {
    let [x0, y0, x1, y1] = a.r#box;
    let frame = crop::load_grey(&a.frame)?;
    let (w, h) = frame.dimensions();
    if x1 >= w || y1 >= h {
        bail!("--box {x0},{y0},{x1},{y1} leaves the {w}x{h} frame {}", a.frame.display());
    }
    let t = image::imageops::crop_imm(&frame, x0, y0, x1 - x0 + 1, y1 - y0 + 1).to_image();
    fsio::write_with(&a.out, |p| t.save_with_format(p, image::ImageFormat::Png).map_err(Into::into))?;
    eprintln!("template {}x{} written to {}", t.width(), t.height(), a.out.display());
    Ok(())
}
