//! `msr blobs` against an independent flood-fill reference on random masks, and its bad input.
mod common;

use common::msr;
use rand::{Rng, SeedableRng};
use serde_json::Value;

/// (area, [x0, y0, x1, y1], [sum_x, sum_y]) per 8-connected component, in raster order of the
/// first pixel: a plain stack flood fill, nothing shared with the firmware.
fn flood_fill(mask: &[bool], w: usize, h: usize) -> Vec<(u64, [u64; 4], [u64; 2])> {
    let mut seen = vec![false; w * h];
    let mut out = Vec::new();
    for start in 0..w * h {
        if !mask[start] || seen[start] {
            continue;
        }
        seen[start] = true;
        let mut stack = vec![start];
        let (mut n, mut b, mut s) = (0u64, [u64::MAX, u64::MAX, 0, 0], [0u64, 0]);
        while let Some(i) = stack.pop() {
            let (x, y) = ((i % w) as i64, (i / w) as i64);
            n += 1;
            b = [
                b[0].min(x as u64),
                b[1].min(y as u64),
                b[2].max(x as u64),
                b[3].max(y as u64),
            ];
            s[0] += x as u64;
            s[1] += y as u64;
            for dy in -1..=1i64 {
                for dx in -1..=1i64 {
                    let (nx, ny) = (x + dx, y + dy);
                    if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                        continue;
                    }
                    let j = ny as usize * w + nx as usize;
                    if mask[j] && !seen[j] {
                        seen[j] = true;
                        stack.push(j);
                    }
                }
            }
        }
        out.push((n, b, s));
    }
    out
}

#[test]
fn agrees_with_flood_fill_on_random_masks() {
    let tmp = tempfile::tempdir().unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let sizes = [
        (1, 1),
        (7, 1),
        (1, 9),
        (75, 58),
        (96, 64),
        (320, 240),
        (33, 17),
    ];
    for (case, &(w, h)) in sizes.iter().cycle().take(21).enumerate() {
        let density = [0.05, 0.3, 0.5, 0.7][case % 4];
        let mask: Vec<bool> = (0..w * h).map(|_| rng.gen_bool(density)).collect();
        let img = image::GrayImage::from_fn(w as u32, h as u32, |x, y| {
            // Any non-zero value is set.
            image::Luma([if mask[y as usize * w + x as usize] {
                1 + (x * 7 + y) as u8 % 255
            } else {
                0
            }])
        });
        let path = tmp.path().join(format!("m{case}.png"));
        img.save(&path).unwrap();
        let min_area = [1u64, 1, 3, 30][case % 4];
        let (ok, out, err) = msr(&[
            "blobs",
            "--mask",
            path.to_str().unwrap(),
            "--min-area",
            &min_area.to_string(),
            "--json",
        ]);
        assert!(ok, "{err}");
        let v: Value = serde_json::from_str(out.trim()).unwrap();
        assert_eq!(v["overflow"], false);
        let got = v["blobs"].as_array().unwrap();
        let want: Vec<_> = flood_fill(&mask, w, h)
            .into_iter()
            .filter(|c| c.0 >= min_area)
            .collect();
        assert_eq!(
            got.len(),
            want.len(),
            "case {case} ({w}x{h}, density {density})"
        );
        for (g, (n, b, s)) in got.iter().zip(&want) {
            assert_eq!(g["area"].as_u64().unwrap(), *n);
            let gb: Vec<u64> = g["box_xyxy"]
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_u64().unwrap())
                .collect();
            assert_eq!(gb, b.to_vec());
            for k in 0..2 {
                let c = g["centroid"][k].as_f64().unwrap();
                assert!((c - s[k] as f64 / *n as f64).abs() < 1e-9, "centroid {c}");
            }
        }
    }
}

#[test]
fn default_min_area_is_one_and_text_output_works() {
    let tmp = tempfile::tempdir().unwrap();
    let mut img = image::GrayImage::new(10, 6);
    img.put_pixel(2, 2, image::Luma([255]));
    img.put_pixel(3, 3, image::Luma([255])); // diagonal: same blob
    img.put_pixel(8, 0, image::Luma([9]));
    let p = tmp.path().join("m.png");
    img.save(&p).unwrap();
    let (ok, out, _) = msr(&["blobs", "--mask", p.to_str().unwrap(), "--json"]);
    assert!(ok);
    assert_eq!(
        out.trim(),
        r#"{"blobs":[{"area":1,"box_xyxy":[8,0,8,0],"centroid":[8.0,0.0]},{"area":2,"box_xyxy":[2,2,3,3],"centroid":[2.5,2.5]}],"overflow":false}"#
    );
    let (ok, out, _) = msr(&["blobs", "--mask", p.to_str().unwrap()]);
    assert!(ok && out.starts_with("2 blobs"), "{out}");
}

#[test]
fn bad_masks_are_one_clear_line() {
    let tmp = tempfile::tempdir().unwrap();
    let corrupt = tmp.path().join("bad.png");
    std::fs::write(&corrupt, b"\x89PNG\r\n\x1a\nnot really").unwrap();
    for (args, want) in [
        (
            vec!["blobs", "--mask", "/nonexistent/mask.png", "--json"],
            "cannot read mask",
        ),
        (
            vec!["blobs", "--mask", corrupt.to_str().unwrap(), "--json"],
            "cannot read mask",
        ),
        (
            vec![
                "blobs",
                "--mask",
                corrupt.to_str().unwrap(),
                "--min-area",
                "0",
            ],
            "--min-area",
        ),
    ] {
        let (ok, out, err) = msr(&args);
        assert!(!ok, "{args:?} succeeded: {out}");
        assert!(err.contains(want), "{args:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(!err.contains("panicked"), "{err}");
    }
}
