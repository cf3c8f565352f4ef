//! Scores for evaluation: AUROC and a frame's detection score.

/// Area under the ROC curve of `scores` against `labels` (true = positive), ties counted half
/// (the Mann-Whitney U statistic). `None` without both classes or with a NaN score.
pub fn auroc(scores: &[f32], labels: &[bool]) -> Option<f64> {
    if scores.len() != labels.len() || scores.iter().any(|s| s.is_nan()) {
        return None;
    }
    let pos = labels.iter().filter(|&&l| l).count();
    let neg = labels.len() - pos;
    if pos == 0 || neg == 0 {
        return None;
    }
    let mut idx: Vec<usize> = (0..scores.len()).collect();
    idx.sort_by(|&a, &b| scores[a].total_cmp(&scores[b]));
    // Sum of positive ranks (1-based, ties get their average rank).
    let mut rank_sum = 0f64;
    let mut i = 0;
    while i < idx.len() {
        let mut j = i;
        while j + 1 < idx.len() && scores[idx[j + 1]] == scores[idx[i]] {
            j += 1;
        }
        let avg = (i + j) as f64 / 2.0 + 1.0;
        rank_sum += avg * idx[i..=j].iter().filter(|&&k| labels[k]).count() as f64;
        i = j + 1;
    }
    let (p, n) = (pos as f64, neg as f64);
    Some((rank_sum - p * (p + 1.0) / 2.0) / (p * n))
}

/// The largest threshold at which a frame still yields a detection: the highest `t` such that
/// some 8-connected component of `{saliency >= t}` has at least `min_area` pixels. Pixels are
/// added from the most salient down, merging components (union-find); `-inf` if no component
/// ever reaches `min_area` (a face smaller than it).
pub fn detection_score(saliency: &[f32], w: usize, min_area: u32) -> f32 {
    let n = saliency.len();
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| saliency[b].total_cmp(&saliency[a]));
    let mut parent: Vec<usize> = (0..n).collect();
    let mut size = vec![0u32; n];
    fn root(p: &mut [usize], mut i: usize) -> usize {
        while p[i] != i {
            p[i] = p[p[i]];
            i = p[i];
        }
        i
    }
    let h = n / w.max(1);
    for &i in &order {
        size[i] = 1;
        let (x, y) = ((i % w) as isize, (i / w) as isize);
        let mut r = i;
        for dy in -1..=1 {
            for dx in -1..=1 {
                let (nx, ny) = (x + dx, y + dy);
                if (dx, dy) == (0, 0) || nx < 0 || ny < 0 || nx >= w as isize || ny >= h as isize {
                    continue;
                }
                let j = ny as usize * w + nx as usize;
                if size[j] == 0 && j != i {
                    continue; // not added yet
                }
                let (a, b) = (root(&mut parent, r), root(&mut parent, j));
                if a != b {
                    parent[b] = a;
                    size[a] += size[b];
                    r = a;
                }
            }
        }
        let r = root(&mut parent, i);
        if size[r] >= min_area {
            return saliency[i];
        }
    }
    f32::NEG_INFINITY
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auroc_known_values() {
        assert_eq!(
            auroc(&[0.1, 0.2, 0.8, 0.9], &[false, false, true, true]),
            Some(1.0)
        );
        assert_eq!(
            auroc(&[0.9, 0.8, 0.2, 0.1], &[false, false, true, true]),
            Some(0.0)
        );
        assert_eq!(auroc(&[0.5, 0.5], &[false, true]), Some(0.5));
        // One positive above two of three negatives.
        let a = auroc(&[0.1, 0.3, 0.7, 0.5], &[false, false, false, true]).unwrap();
        assert!((a - 2.0 / 3.0).abs() < 1e-12);
        assert_eq!(auroc(&[0.1], &[true]), None);
        assert_eq!(auroc(&[f32::NAN, 0.1], &[true, false]), None);
    }

    #[test]
    fn detection_score_is_the_highest_threshold_keeping_a_blob() {
        // 5x3: a diagonal pair of 9s (8-connected), a lone 10.
        #[rustfmt::skip]
        let s = [
            10.0, 0.0, 0.0, 0.0, 0.0,
             0.0, 0.0, 9.0, 0.0, 0.0,
             0.0, 0.0, 0.0, 9.5, 0.0,
        ];
        assert_eq!(detection_score(&s, 5, 1), 10.0);
        assert_eq!(detection_score(&s, 5, 2), 9.0);
        assert_eq!(detection_score(&s, 5, 3), 0.0);
        assert_eq!(detection_score(&s, 5, 16), f32::NEG_INFINITY);
    }
}
