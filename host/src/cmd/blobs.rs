//! `msr blobs`: list the 8-connected blobs of a binary mask with the firmware's blob stage.
use crate::detect::pipeline::Blob;
use anyhow::{ensure, Context, Result};
use serde_json::json;
use std::path::PathBuf;

/// `msr blobs`'s flags: the mask, the smallest blob listed, the output format.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The mask: any PNG; non-zero pixels (after conversion to grey) are set
    #[arg(long)]
    pub mask: PathBuf,
    /// Smallest blob reported, in pixels
    #[arg(long, default_value_t = 1)]
    pub min_area: u32,
    /// Print JSON instead of a table
    #[arg(long)]
    pub json: bool,
}

/// Reads the mask PNG and prints its blobs of at least `--min-area` pixels.
pub fn run(args: Args) -> Result<()> {
    ensure!(args.min_area >= 1, "--min-area must be at least 1");
    let img = image::open(&args.mask)
        .with_context(|| format!("cannot read mask {}", args.mask.display()))?
        .to_luma8();
    let (w, h) = (img.width() as usize, img.height() as usize);
    let mask: Vec<bool> = img.as_raw().iter().map(|&v| v != 0).collect();
    let (blobs, overflow) = find(&mask, w, h, args.min_area)?;
    if args.json {
        println!("{}", json!({"blobs": blobs, "overflow": overflow}));
    } else {
        println!(
            "{} blobs of at least {} px in {}x{}{}",
            blobs.len(),
            args.min_area,
            w,
            h,
            if overflow {
                " (overflow: more blobs than the stage holds)"
            } else {
                ""
            }
        );
        for b in &blobs {
            println!(
                "  area {:6}  box {:?}  centroid ({:.2}, {:.2})",
                b.area, b.box_xyxy, b.centroid[0], b.centroid[1]
            );
        }
    }
    Ok(())
}

/// Blobs with at least `min_area` pixels, in scan order of their first pixel, and whether the
/// blob stage ran out of room.
pub fn find(mask: &[bool], w: usize, h: usize, min_area: u32) -> Result<(Vec<Blob>, bool)> {
    ensure!(
        mask.len() == w * h,
        "mask has {} pixels, not {w}x{h}",
        mask.len()
    );
    let (all, overflow) = crate::detect::blobs::label(mask, w, h)?;
    Ok((
        all.into_iter().filter(|b| b.area >= min_area).collect(),
        overflow,
    ))
}
