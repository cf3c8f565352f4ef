use super::*;
use proptest::prelude::*;

/// Independent reference: breadth-first flood fill over 8 neighbours, as OpenCV's
/// connectedComponentsWithStats(connectivity = 8) defines the components.
fn reference(mask: &[u8], w: usize, h: usize) -> Vec<Blob> {
    let mut seen = vec![false; w * h];
    let mut out = Vec::new();
    for start in 0..w * h {
        if mask[start] == 0 || seen[start] {
            continue;
        }
        let mut b = Blob {
            area: 0,
            x0: u16::MAX,
            y0: u16::MAX,
            x1: 0,
            y1: 0,
            sum_x: 0,
            sum_y: 0,
            first: start as u32,
        };
        let mut queue = std::collections::VecDeque::from([start]);
        seen[start] = true;
        while let Some(i) = queue.pop_front() {
            let (x, y) = (i % w, i / w);
            b.area += 1;
            b.x0 = b.x0.min(x as u16);
            b.y0 = b.y0.min(y as u16);
            b.x1 = b.x1.max(x as u16);
            b.y1 = b.y1.max(y as u16);
            b.sum_x += x as u64;
            b.sum_y += y as u64;
            for dy in -1i32..=1 {
                for dx in -1i32..=1 {
                    let (nx, ny) = (x as i32 + dx, y as i32 + dy);
                    if nx < 0 || ny < 0 || nx >= w as i32 || ny >= h as i32 {
                        continue;
                    }
                    let j = ny as usize * w + nx as usize;
                    if mask[j] != 0 && !seen[j] {
                        seen[j] = true;
                        queue.push_back(j);
                    }
                }
            }
        }
        out.push(b);
    }
    out
}

fn label_all<const L: usize, const R: usize>(
    lab: &mut Labeller<L, R>,
    mask: &[u8],
    w: usize,
    h: usize,
) -> (Vec<Blob>, Summary) {
    let mut got = Vec::new();
    let sum = lab.label(mask, w, h, |b| got.push(*b)).unwrap();
    got.sort_by_key(|b| b.first);
    (got, sum)
}

fn parse(rows: &[&str]) -> (Vec<u8>, usize, usize) {
    let w = rows[0].len();
    let mask = rows
        .iter()
        .flat_map(|r| r.bytes().map(|c| (c == b'#') as u8))
        .collect();
    (mask, w, rows.len())
}

#[test]
fn shapes_that_merge_late_and_touch_diagonally() {
    let mut lab = Box::new(FaceLabeller::new());
    for rows in [
        // A U: two runs that join only at the bottom.
        &["#...#", "#...#", "#####"][..],
        // A diagonal chain is one component under 8-connectivity.
        &["#....", ".#...", "..#..", "...#.", "....#"][..],
        // A W with three prongs joined below, and a separate dot.
        &["#.#.#..#", "#.#.#...", "#####..."][..],
        // A checkerboard is one component.
        &["#.#.#", ".#.#.", "#.#.#"][..],
        // Nested ring and dot.
        &["#####", "#...#", "#.#.#", "#...#", "#####"][..],
        &["....."][..],
        &["#####"][..],
    ] {
        let (m, w, h) = parse(rows);
        let (got, sum) = label_all(&mut lab, &m, w, h);
        assert_eq!(got, reference(&m, w, h), "{rows:?}");
        assert!(!sum.overflow);
        assert_eq!(sum.components as usize, got.len());
    }
}

#[test]
fn centroid_is_the_mean_pixel() {
    let (m, w, h) = parse(&["##..", "##..", "...#"]);
    let (got, _) = label_all(&mut Box::new(FaceLabeller::new()), &m, w, h);
    assert_eq!(got[0].centroid(), [0.5, 0.5]);
    assert_eq!(got[0].area, 4);
    assert_eq!((got[0].x0, got[0].y0, got[0].x1, got[0].y1), (0, 0, 1, 1));
    assert_eq!(got[1].centroid(), [3.0, 2.0]);
}

#[test]
fn bad_shapes_are_refused() {
    let mut lab = Box::new(FaceLabeller::new());
    let m = vec![1u8; 200 * 2];
    assert_eq!(lab.label(&m, 0, 1, |_| {}), Err(MaskError::Shape));
    assert_eq!(lab.label(&m, 10, 0, |_| {}), Err(MaskError::Shape));
    assert_eq!(
        lab.label(&m, 200, 2, |_| {}),
        Err(MaskError::Shape),
        "wider than the run buffers"
    );
    assert_eq!(
        lab.label(&m[..10], 4, 3, |_| {}),
        Err(MaskError::Shape),
        "mask too short"
    );
    assert_eq!(FaceLabeller::max_width(), 97);
    // The widest face, every other pixel set: the most runs a row can have.
    let w = 96;
    let m: Vec<u8> = (0..w * 64)
        .map(|i| ((i % w) % 2 == 0 && (i / w) % 2 == 0) as u8)
        .collect();
    let (got, sum) = label_all(&mut lab, &m, w, 64);
    assert_eq!(got, reference(&m, w, 64));
    assert_eq!((got.len(), sum.overflow), (48 * 32, false));
}

#[test]
fn overflow_is_reported_and_what_is_kept_is_exact() {
    // Four slots for a mask with many components at once.
    let mut lab = Box::new(Labeller::<4, 49>::new());
    let (m, w, h) = parse(&[
        "#.#.#.#.#.#.",
        "#.#.#.#.#.#.",
        "############",
        "............",
        "#..#..#..#..",
    ]);
    let (got, sum) = label_all(&mut lab, &m, w, h);
    assert!(sum.overflow);
    let want = reference(&m, w, h);
    for b in &got {
        assert!(want.contains(b), "{b:?} is not a true component");
    }
    assert!(got.len() < want.len());
    assert_eq!(sum.components as usize, got.len());
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, ..ProptestConfig::default() })]

    #[test]
    fn agrees_with_flood_fill(w in 1usize..=97, h in 1usize..=40, density in 0u32..100, seed: u64) {
        let mut s = seed | 1;
        let m: Vec<u8> = (0..w * h).map(|_| {
            s ^= s << 13; s ^= s >> 7; s ^= s << 17;
            ((s % 100) < density as u64) as u8
        }).collect();
        let mut lab = Box::new(FaceLabeller::new());
        let (got, sum) = label_all(&mut lab, &m, w, h);
        prop_assert!(!sum.overflow);
        prop_assert_eq!(got, reference(&m, w, h));
    }

    /// Told the mask's own row counts, the labeller skips the empty rows and finds the same
    /// components, in the same order, on masks with whole empty bands.
    #[test]
    fn row_counts_change_nothing(w in 1usize..=97, h in 1usize..=40, density in 0u32..100, band in 0usize..8, seed: u64) {
        let mut s = seed | 1;
        let m: Vec<u8> = (0..w * h).map(|i| {
            s ^= s << 13; s ^= s >> 7; s ^= s << 17;
            ((i / w) % 8 >= band && (s % 100) < density as u64) as u8
        }).collect();
        let counts: Vec<u16> = m.chunks(w).map(|r| r.iter().filter(|&&v| v != 0).count() as u16).collect();
        let (mut a, mut b) = (Vec::new(), Vec::new());
        let mut lab = Box::new(FaceLabeller::new());
        let sa = lab.label(&m, w, h, |x| a.push(*x)).unwrap();
        let sb = lab.label_rows(&m, w, h, &counts, |x| b.push(*x)).unwrap();
        prop_assert_eq!(sa, sb);
        prop_assert_eq!(a, b);
    }

    #[test]
    fn small_capacity_never_reports_a_wrong_component(w in 1usize..=30, h in 1usize..=20, density in 0u32..100, seed: u64, cap in 0usize..3) {
        let mut s = seed | 1;
        let m: Vec<u8> = (0..w * h).map(|_| {
            s ^= s << 13; s ^= s >> 7; s ^= s << 17;
            ((s % 100) < density as u64) as u8
        }).collect();
        let want = reference(&m, w, h);
        let got = match cap {
            0 => label_all(&mut Box::new(Labeller::<1, 16>::new()), &m, w, h),
            1 => label_all(&mut Box::new(Labeller::<3, 16>::new()), &m, w, h),
            _ => label_all(&mut Box::new(Labeller::<6, 16>::new()), &m, w, h),
        };
        for b in &got.0 {
            prop_assert!(want.contains(b));
        }
        if !got.1.overflow {
            prop_assert_eq!(&got.0, &want);
        }
    }
}

mod merging {
    use super::super::merge::{pick, MAX_FRAGMENTS};
    use super::*;
    use msr_shared::blob::Merge;

    /// Independent reference: flood-fill components, fragments of at least `fragment` pixels,
    /// groups joined by union until no two groups' boxes are within the margin, then the
    /// largest group (earliest first pixel on ties) of at least `min_area`.
    fn reference_pick(mask: &[u8], w: usize, h: usize, min_area: u16, merge: Merge) -> Option<Blob> {
        let comps = reference(mask, w, h);
        let best = |v: &[Blob]| {
            v.iter()
                .filter(|b| b.area >= min_area as u32)
                .min_by_key(|b| (core::cmp::Reverse(b.area), b.first))
                .copied()
        };
        if !merge.is_on() {
            return best(&comps);
        }
        let frags: Vec<Blob> = comps.iter().filter(|b| b.area >= merge.fragment as u32).copied().collect();
        if frags.len() > MAX_FRAGMENTS {
            return best(&comps);
        }
        let mut group: Vec<usize> = (0..frags.len()).collect();
        let m = merge.margin as i64;
        loop {
            let mut boxes: Vec<Option<Blob>> = vec![None; frags.len()];
            for (i, f) in frags.iter().enumerate() {
                let g = &mut boxes[group[i]];
                match g {
                    None => *g = Some(*f),
                    Some(b) => b.merge(f),
                }
            }
            let mut joined = false;
            'pairs: for a in 0..frags.len() {
                for b in 0..frags.len() {
                    if let (Some(x), Some(y)) = (boxes[a], boxes[b]) {
                        let near = (x.x0 as i64) <= y.x1 as i64 + m
                            && (y.x0 as i64) <= x.x1 as i64 + m
                            && (x.y0 as i64) <= y.y1 as i64 + m
                            && (y.y0 as i64) <= x.y1 as i64 + m;
                        if a != b && near {
                            for g in group.iter_mut() {
                                if *g == b {
                                    *g = a;
                                }
                            }
                            joined = true;
                            break 'pairs;
                        }
                    }
                }
            }
            if !joined {
                let groups: Vec<Blob> = boxes.into_iter().flatten().collect();
                return best(&groups);
            }
        }
    }

    fn run(mask: &[u8], w: usize, h: usize, min_area: u16, merge: Merge) -> Option<Blob> {
        pick(&mut Box::new(FaceLabeller::new()), mask, w, h, &[], min_area, merge).0
    }

    #[test]
    fn pieces_join_within_the_margin_only() {
        // Three 2 x 2 pieces with two empty columns between them, and a lone pixel.
        let (m, w, h) = parse(&["##..##..##..#", "##..##..##..."]);
        let off = run(&m, w, h, 12, Merge::OFF);
        assert_eq!(off, None, "no piece reaches 12 px");
        assert_eq!(run(&m, w, h, 12, Merge { margin: 2, fragment: 3 }), None);
        let b = run(&m, w, h, 12, Merge { margin: 3, fragment: 3 }).unwrap();
        // The lone pixel is below the fragment size: not counted, not in the box.
        assert_eq!((b.area, b.x0, b.y0, b.x1, b.y1, b.first), (12, 0, 0, 9, 1, 0));
        assert_eq!(b.centroid(), [4.5, 0.5]);
        // Fragment size 1 takes the lone pixel in too.
        let b = run(&m, w, h, 12, Merge { margin: 3, fragment: 1 }).unwrap();
        assert_eq!((b.area, b.x1), (13, 12));
    }

    #[test]
    fn a_grown_box_reaches_further() {
        // A (rows 2-3) and B (rows 5-6) are near; C (top right) is near neither (too far
        // right of A, too far above B) but near their union's box.
        let (m, w, h) = parse(&[
            "......##", //
            "......##", //
            "##......", //
            "##......", //
            "........", //
            "...##...", //
            "...##...",
        ]);
        let merge = Merge { margin: 2, fragment: 4 };
        let b = run(&m, w, h, 12, merge).unwrap();
        assert_eq!((b.area, b.x0, b.y0, b.x1, b.y1, b.first), (12, 0, 0, 7, 6, 6));
        // Without C the union is only A and B.
        let mut no_c = m.clone();
        no_c[6] = 0;
        no_c[7] = 0;
        no_c[w + 6] = 0;
        no_c[w + 7] = 0;
        assert_eq!(run(&no_c, w, h, 8, merge).map(|b| b.area), Some(8));
        assert_eq!(Some(b), reference_pick(&m, w, h, 12, merge));
    }

    #[test]
    fn too_many_fragments_fall_back_to_the_papers_winner() {
        // 40 lone 2 x 2 squares and one 3 x 3: more fragments than kept, so no merge.
        let w = 90;
        let h = 9;
        let mut m = vec![0u8; w * h];
        for k in 0..40 {
            let (x, y) = ((k % 20) * 4, (k / 20) * 4);
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                m[(y + dy) * w + x + dx] = 1;
            }
        }
        for dy in 0..3 {
            for dx in 0..3 {
                m[(6 + dy) * w + 84 + dx] = 1;
            }
        }
        let merge = Merge { margin: 3, fragment: 4 };
        let b = run(&m, w, h, 9, merge).unwrap();
        assert_eq!((b.area, b.x0), (9, 84));
        assert_eq!(Some(b), run(&m, w, h, 9, Merge::OFF));
        assert_eq!(Some(b), reference_pick(&m, w, h, 9, merge));
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

        #[test]
        fn agrees_with_the_reference(
            w in 1usize..=96, h in 1usize..=64, density in 0u32..25, seed: u64,
            margin in 0u8..=6, fragment in 1u16..=6, min_area in 1u16..=40,
        ) {
            let mut s = seed | 1;
            let m: Vec<u8> = (0..w * h).map(|_| {
                s ^= s << 13; s ^= s >> 7; s ^= s << 17;
                ((s % 100) < density as u64) as u8
            }).collect();
            let merge = if margin == 0 { Merge::OFF } else { Merge { margin, fragment: fragment.min(min_area) } };
            prop_assert_eq!(run(&m, w, h, min_area, merge), reference_pick(&m, w, h, min_area, merge));
        }
    }
}
