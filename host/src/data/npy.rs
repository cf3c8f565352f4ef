//! The one `.npy` reader and writer: 2-d float arrays (the error statistics), row-major.
use anyhow::{bail, ensure, Context, Result};
use std::path::Path;

/// Writes an `h x w` float64 array (like the published statistics).
pub fn write(path: &Path, h: usize, w: usize, data: &[f64]) -> Result<()> {
    use npyz::WriterBuilder;
    ensure!(data.len() == h * w, "npy data has {} values for {h}x{w}", data.len());
    // Through a temporary file and a rename, so a failed run leaves the old file whole.
    crate::fsio::write_with(path, |tmp| {
        let f = std::fs::File::create(tmp)?;
        let mut wr = npyz::WriteOptions::new()
            .default_dtype()
            .shape(&[h as u64, w as u64])
            .writer(std::io::BufWriter::new(f))
            .begin_nd()?;
        wr.extend(data.iter().copied())?;
        wr.finish()?;
        Ok(())
    })
}

/// Reads a 2-d float64 or float32 array as `(h, w, values)`, row-major (a Fortran-order file is
/// transposed); non-finite values are an error.
pub fn read(path: &Path) -> Result<(usize, usize, Vec<f64>)> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let npy = npyz::NpyFile::new(&bytes[..]).with_context(|| format!("{} is not a valid .npy file", path.display()))?;
    let shape = npy.shape().to_vec();
    let [h, w] = shape[..] else { bail!("{}: expected a 2-d array, got shape {shape:?}", path.display()) };
    // The header's shape is bounded by the file before anything is sized by it.
    ensure!(
        h.checked_mul(w).is_some_and(|n| n <= bytes.len() as u64),
        "{}: shape {shape:?} needs more values than the file holds",
        path.display()
    );
    let (h, w) = (h as usize, w as usize);
    let truncated = || format!("{} is truncated or unreadable (fewer values than its header's shape)", path.display());
    let fortran = npy.order() == npyz::Order::Fortran;
    let v: Vec<f64> = match npy.dtype() {
        npyz::DType::Plain(t) if t.type_char() == npyz::TypeChar::Float && t.size_field() == 8 => {
            npy.into_vec::<f64>().with_context(truncated)?
        }
        npyz::DType::Plain(t) if t.type_char() == npyz::TypeChar::Float && t.size_field() == 4 => {
            npy.into_vec::<f32>().with_context(truncated)?.into_iter().map(f64::from).collect()
        }
        d => bail!("{}: dtype {} is not float64 or float32", path.display(), d.descr()),
    };
    ensure!(v.len() == h * w, "{} holds {} values, its shape says {}", path.display(), v.len(), h * w);
    ensure!(v.iter().all(|x| x.is_finite()), "{}: non-finite values", path.display());
    if fortran {
        // Column-major on disk: transpose to row-major.
        return Ok((h, w, (0..h * w).map(|i| v[(i % w) * h + i / w]).collect()));
    }
    Ok((h, w, v))
}

/// [`read`], requiring the shape `(h, w)`.
pub fn read_shaped(path: &Path, (h, w): (usize, usize)) -> Result<Vec<f64>> {
    let (rh, rw, v) = read(path)?;
    ensure!((rh, rw) == (h, w), "{} has shape [{rh}, {rw}], expected [{h}, {w}]", path.display());
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_bad_files() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("mu.npy");
        let data: Vec<f64> = (0..6).map(|i| i as f64 * 0.25).collect();
        write(&p, 2, 3, &data).unwrap();
        assert_eq!(read(&p).unwrap(), (2, 3, data.clone()));
        assert_eq!(read_shaped(&p, (2, 3)).unwrap(), data);
        assert!(read_shaped(&p, (3, 2)).is_err());
        std::fs::write(&p, b"not npy").unwrap();
        assert!(read(&p).is_err());
        assert!(read(&dir.path().join("missing.npy")).is_err());
    }
}
