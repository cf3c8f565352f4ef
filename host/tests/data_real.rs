//! Loading the published real frames: crops, head angles, marks.
mod common;

use common::real_dir;
use msr_host::data::crop::CropMode;
use msr_host::data::{Dataset, Layout};
use msr_sim::layout::Split;

#[test]
fn loads_the_published_frames() {
    let Some(dir) = real_dir() else { return };
    let t = std::time::Instant::now();
    let ds = Dataset::load(&dir, CropMode::Pixel).unwrap();
    eprintln!("loaded {} frames in {:?}", ds.samples.len(), t.elapsed());
    assert_eq!(ds.layout, Layout::Published);
    assert_eq!(ds.samples.len(), 15);
    assert_eq!(ds.face_size(), (58, 75));
    assert_eq!(ds.split(Split::Test).count(), 15);
    let marked: Vec<_> = ds.samples.iter().filter(|s| s.mark.is_some()).collect();
    assert_eq!(marked.len(), 9);
    for s in &ds.samples {
        let c = s.crop();
        eprintln!(
            "{} crop {:?} score {:.0}",
            s.file.display(),
            c,
            s.face.score
        );
        assert_eq!((c.width, c.height), (75, 58));
        assert!(c.x + 75 <= 320 && c.y + 58 <= 240);
        assert_eq!(s.face_unit().len(), 58 * 75);
        if let Some(m) = &s.mark {
            // The pasted marks are on the face: wholly inside the crop.
            assert_eq!(
                m.pixels_in_face(),
                m.pixels as usize,
                "{}",
                s.file.display()
            );
        }
    }
    // The windows OpenCV 5.0.0 picks (cv2.matchTemplate TM_CCOEFF + minMaxLoc on cv2.cvtColor grey).
    let opencv = [
        ("test1.png", 122, 92),
        ("test2.png", 139, 79),
        ("test3.png", 140, 119),
        ("test4.png", 113, 79),
        ("test5.png", 103, 97),
        ("test6.png", 103, 115),
    ];
    for (f, x, y) in opencv {
        let s = ds.samples.iter().find(|s| s.file.ends_with(f)).unwrap();
        assert_eq!((s.crop().x, s.crop().y), (x, y), "{f}");
    }
    // The marked frames are test2.png with a mark pasted: the crop must not move much.
    let base = ds
        .samples
        .iter()
        .find(|s| s.file.ends_with("test2.png"))
        .unwrap()
        .crop();
    for m in &marked {
        let c = m.crop();
        assert!(
            c.x.abs_diff(base.x) <= 2 && c.y.abs_diff(base.y) <= 2,
            "{:?} vs {:?}",
            c,
            base
        );
    }
    let train = Dataset::load_split(&dir, Some(Split::Train), CropMode::Pixel).unwrap();
    assert!(train.samples.is_empty());
}
