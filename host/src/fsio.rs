//! Files in and out, the way every `msr` command uses them: outputs are written to a temporary
//! file beside the target and renamed over it (a failed or interrupted run leaves the old file
//! whole), every error names the path, and output paths are checked against the inputs and each
//! other before any work starts.
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};

/// The temporary name beside `path` that [`write_with`] writes first: hidden, with this
/// process's id, and the same extension (savers pick the format by it).
pub fn temp_beside(path: &Path) -> PathBuf {
    let name = path.file_stem().map_or("out".into(), |s| s.to_string_lossy().into_owned());
    let ext = path
        .extension()
        .map_or(String::new(), |e| format!(".{}", e.to_string_lossy()));
    path.with_file_name(format!(".{name}.tmp{}{ext}", std::process::id()))
}

/// Writes `path` through `save(temporary path)` and a rename; on any error the temporary file is
/// removed and `path` is left as it was.
pub fn write_with(path: &Path, save: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    if path.is_dir() {
        bail!("cannot write {}: it is a folder", path.display());
    }
    refuse_special(path)?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot write {}: cannot create {}", path.display(), dir.display()))?;
    }
    let tmp = temp_beside(path);
    let done = save(&tmp).and_then(|()| {
        std::fs::rename(&tmp, path).with_context(|| format!("cannot write {}", path.display()))
    });
    if done.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    done.map_err(|e| untemp(e, &tmp, path))
        .with_context(|| format!("cannot write {}", path.display()))
        .map_err(dedupe)
}

/// An error of a write to `tmp` told in the user's words: the temporary file's path, name and
/// extension (a saver that picks the format by the extension names it) become `path`'s.
fn untemp(e: anyhow::Error, tmp: &Path, path: &Path) -> anyhow::Error {
    let msgs: Vec<String> = e.chain().map(|c| c.to_string()).collect();
    let name = |p: &Path| p.file_name().map(|n| n.to_string_lossy().into_owned());
    let ext = |p: &Path| p.extension().map(|n| n.to_string_lossy().into_owned());
    let mut swaps = vec![(tmp.display().to_string(), path.display().to_string())];
    if let (Some(t), Some(p)) = (name(tmp), name(path)) {
        swaps.push((t, p));
    }
    match (ext(tmp), ext(path)) {
        (Some(t), Some(p)) if t != p => swaps.push((t, p)),
        (Some(t), None) => swaps.extend([(format!(".\"{t}\""), "(none)".into()), (t, String::new())]),
        _ => {}
    }
    if !msgs.iter().any(|m| swaps.iter().any(|(t, _)| m.contains(t.as_str()))) {
        return e;
    }
    let fix = |m: &str| swaps.iter().fold(m.to_string(), |m, (t, p)| m.replace(t.as_str(), p));
    let mut it = msgs.iter().rev();
    let mut out = anyhow::anyhow!(fix(it.next().map_or("", |m| m.as_str())));
    for m in it {
        out = out.context(fix(m));
    }
    out
}

/// Refuses to write over a device, a FIFO or a socket (or a link to one): the rename would
/// replace the node with a regular file, and writing into it is no file the user keeps.
pub fn refuse_special(path: &Path) -> Result<()> {
    let special = |m: std::fs::Metadata| {
        let t = m.file_type();
        !(t.is_file() || t.is_dir() || t.is_symlink())
    };
    let own = std::fs::symlink_metadata(path).map(special).unwrap_or(false);
    let target = std::fs::metadata(path).map(special).unwrap_or(false);
    if own || target {
        bail!(
            "{} is a device or another special file, not a regular file: refusing to write it (give a file path)",
            path.display()
        );
    }
    Ok(())
}

/// A log written as it grows (`msr servos --bus-log`): nothing happens to `path` until the first
/// bytes come; then a new file is made beside it and renamed over it (a link is replaced, never
/// followed), and the rest goes into that file.
pub struct LazyLog {
    path: PathBuf,
    file: Option<std::fs::File>,
}

impl LazyLog {
    /// Checks `path` now (a folder or a special file is refused); opens nothing.
    pub fn new(path: &Path) -> Result<LazyLog> {
        if path.is_dir() {
            bail!("cannot write {}: it is a folder", path.display());
        }
        refuse_special(path)?;
        Ok(LazyLog { path: path.to_path_buf(), file: None })
    }

    fn open(&mut self) -> std::io::Result<&mut std::fs::File> {
        if self.file.is_none() {
            if let Some(dir) = self.path.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::create_dir_all(dir)?;
            }
            let tmp = temp_beside(&self.path);
            let f = std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp)?;
            if let Err(e) = std::fs::rename(&tmp, &self.path) {
                let _ = std::fs::remove_file(&tmp);
                return Err(e);
            }
            self.file = Some(f);
        }
        Ok(self.file.as_mut().expect("opened above"))
    }
}

impl std::io::Write for LazyLog {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        if buf.is_empty() {
            return Ok(0);
        }
        let path = self.path.display().to_string();
        self.open()
            .and_then(|f| f.write(buf))
            .map_err(|e| std::io::Error::new(e.kind(), format!("writing {path}: {e}")))
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.file.as_mut().map_or(Ok(()), |f| f.flush())
    }
}

/// Writes `bytes` to `path` atomically (temporary file + rename).
pub fn write(path: &Path, bytes: impl AsRef<[u8]>) -> Result<()> {
    write_with(path, |tmp| {
        std::fs::write(tmp, bytes.as_ref()).map_err(anyhow::Error::from)
    })
}

/// Reads a whole file; the error names it.
pub fn read(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))
}

/// A model blob file's bytes, once they parse as a model (the one reader of model files).
pub fn read_blob(path: &Path) -> Result<Vec<u8>> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read model {}", path.display()))?;
    msr_shared::blob::Model::parse(&bytes).map_err(|e| anyhow::anyhow!("model {}: {e}", path.display()))?;
    Ok(bytes)
}

/// `cannot write X: cannot write X: why` -> `cannot write X: why`.
fn dedupe(e: anyhow::Error) -> anyhow::Error {
    let msgs: Vec<String> = e.chain().map(|c| c.to_string()).collect();
    if msgs.len() >= 2 && msgs[0] == msgs[1] {
        let mut it = msgs.into_iter().skip(1).collect::<Vec<_>>();
        let last = it.pop().unwrap_or_default();
        let mut out = anyhow::anyhow!(last);
        while let Some(m) = it.pop() {
            out = out.context(m);
        }
        return out;
    }
    e
}

/// One path as the file system sees it, for comparing: canonical when it exists, else its
/// canonical parent joined with the name.
fn resolved(p: &Path) -> PathBuf {
    if let Ok(c) = p.canonicalize() {
        return c;
    }
    let parent = p.parent().filter(|q| !q.as_os_str().is_empty()).unwrap_or(Path::new("."));
    match (parent.canonicalize(), p.file_name()) {
        (Ok(d), Some(n)) => d.join(n),
        _ => p.to_path_buf(),
    }
}

/// Refuses, before any work, an output that names an input (or lies inside an input folder) or
/// another output. `inputs` and `outputs` are `(flag, path)`.
pub fn check_outputs(inputs: &[(&str, &Path)], outputs: &[(&str, &Path)]) -> Result<()> {
    for (i, (of, o)) in outputs.iter().enumerate() {
        let ro = resolved(o);
        for (inf, inp) in inputs {
            let ri = resolved(inp);
            if ro == ri {
                bail!(
                    "{of} {} is the same file as {inf}: refusing to overwrite an input",
                    o.display()
                );
            }
        }
        for (of2, o2) in &outputs[i + 1..] {
            if resolved(o2) == ro {
                bail!("{of} and {of2} both name {}", o.display());
            }
        }
    }
    Ok(())
}

/// Refuses an output folder that is an input folder.
pub fn check_out_dir(inputs: &[(&str, &Path)], flag: &str, out: &Path) -> Result<()> {
    let ro = resolved(out);
    for (inf, inp) in inputs {
        let ri = resolved(inp);
        if ro == ri {
            bail!(
                "{flag} {} is {inf} {}: refusing to write over an input",
                out.display(),
                inp.display()
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failed_write_leaves_the_old_file_whole() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("a.json");
        write(&p, b"old").unwrap();
        let e = write_with(&p, |tmp| {
            std::fs::write(tmp, b"half")?;
            bail!("disk full")
        })
        .unwrap_err();
        assert_eq!(std::fs::read(&p).unwrap(), b"old");
        assert!(format!("{e:#}").contains(&p.display().to_string()), "{e:#}");
        assert_eq!(std::fs::read_dir(d.path()).unwrap().count(), 1, "temporary file left");
        write(&p, b"new").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"new");
    }

    #[test]
    fn outputs_may_not_name_inputs_or_each_other() {
        let d = tempfile::tempdir().unwrap();
        let a = d.path().join("a.png");
        std::fs::write(&a, b"x").unwrap();
        let dotted = d.path().join(".").join("a.png");
        let e = check_outputs(&[("--image", &a)], &[("--png", &dotted)]).unwrap_err();
        assert!(e.to_string().contains("same file as --image"), "{e}");
        let b = d.path().join("b.json");
        let e = check_outputs(&[], &[("--out", &b), ("--report", &b)]).unwrap_err();
        assert!(e.to_string().contains("both name"), "{e}");
        check_outputs(&[("--image", &a)], &[("--png", &b)]).unwrap();
        let e = check_out_dir(&[("--data", d.path())], "--out", &d.path().join(".")).unwrap_err();
        assert!(e.to_string().contains("refusing"), "{e}");
    }
}
