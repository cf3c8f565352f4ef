//! Reading a rosbag2 recording: a bag folder (`metadata.yaml` with `.mcap` or `.db3` files, the
//! ones it lists, in its order) or one `.mcap` / `.db3` file. MCAP through the `mcap` crate, SQLite3 through
//! `rusqlite` (its bundled SQLite). Messages come out raw (CDR bytes) with their topic's type.
use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One topic of a bag.
#[derive(Clone, Debug, PartialEq)]
pub struct Topic {
    /// The topic's name (`/camera/image`).
    pub name: String,
    /// e.g. `sensor_msgs/msg/Image`.
    pub type_name: String,
    /// Messages on the topic, all storage files together.
    pub messages: u64,
}

/// The storage format of a bag file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Storage {
    /// An `.mcap` file.
    Mcap,
    /// A `.db3` file (rosbag2's SQLite3 storage).
    Sqlite3,
}

/// An opened bag: its storage files, in order.
#[derive(Clone, Debug)]
pub struct Bag {
    /// The bag folder or the single file as given.
    pub path: PathBuf,
    /// The storage files read, in the order `metadata.yaml` lists them, with their format.
    pub files: Vec<(PathBuf, Storage)>,
    /// Storage files in the bag's folder that its metadata does not list: not read.
    pub unlisted: Vec<PathBuf>,
}

fn storage_of(p: &Path) -> Option<Storage> {
    match p.extension().and_then(|e| e.to_str()) {
        Some("mcap") => Some(Storage::Mcap),
        Some("db3") => Some(Storage::Sqlite3),
        _ => None,
    }
}

/// The value of a top-level-looking `key: value` line of `metadata.yaml` (enough for the two
/// keys read here; the file lists the storage files too, which are found by their names).
fn yaml_value(text: &str, key: &str) -> Option<String> {
    text.lines().find_map(|l| {
        let l = l.trim();
        l.strip_prefix(key)?.strip_prefix(':').map(|v| v.trim().trim_matches(['"', '\'']).to_string())
    })
}

/// The storage files `metadata.yaml` lists under `relative_file_paths`, in its order: block
/// items (`- name`, at the key's indentation or deeper, as rosbag2 and `rosbags` write them) or
/// a flow list (`[a, b]`). `None` when the key is missing.
fn yaml_file_list(text: &str) -> Option<Vec<String>> {
    let unquote = |v: &str| v.trim().trim_matches(['"', '\'']).to_string();
    let mut lines = text.lines();
    let (indent, rest) = lines.by_ref().find_map(|l| {
        let t = l.trim_start();
        let v = t.strip_prefix("relative_file_paths")?.trim_start().strip_prefix(':')?;
        Some((l.len() - t.len(), v.trim().to_string()))
    })?;
    if let Some(flow) = rest.strip_prefix('[') {
        let inner = flow.trim_end().strip_suffix(']')?;
        return Some(inner.split(',').map(unquote).filter(|v| !v.is_empty()).collect());
    }
    if !rest.is_empty() {
        return Some(Vec::new());
    }
    let mut out = Vec::new();
    for l in lines {
        let t = l.trim_start();
        if t.is_empty() || t.starts_with('#') {
            continue;
        }
        match t.strip_prefix('-') {
            Some(v) if l.len() - t.len() >= indent && (v.is_empty() || v.starts_with(' ')) => out.push(unquote(v)),
            _ => break,
        }
    }
    Some(out)
}

impl Bag {
    /// Opens a bag folder or a single `.mcap` / `.db3` file, checking its metadata and that every
    /// file it lists is there; no message is read yet.
    pub fn open(path: &Path) -> Result<Bag> {
        if path.is_file() {
            let Some(s) = storage_of(path) else {
                bail!("bag {}: not a bag folder, an .mcap or a .db3 file", path.display())
            };
            return Ok(Bag { path: path.into(), files: vec![(path.into(), s)], unlisted: Vec::new() });
        }
        if !path.is_dir() {
            if path.exists() {
                bail!("bag {}: not a bag folder, an .mcap or a .db3 file (a device, FIFO or socket)", path.display());
            }
            bail!("bag {} does not exist", path.display());
        }
        let meta = path.join("metadata.yaml");
        if !meta.is_file() {
            bail!("bag {}: no metadata.yaml (a rosbag2 folder has one)", path.display());
        }
        let bytes = std::fs::read(&meta).with_context(|| format!("cannot read {}", meta.display()))?;
        let Ok(text) = String::from_utf8(bytes) else {
            bail!("bag {}: {} is not rosbag2 metadata (not UTF-8 text)", path.display(), meta.display())
        };
        // rosbag2's own compression wraps files (.mcap.zstd) or each message; neither is read.
        if let Some(m) = yaml_value(&text, "compression_mode").filter(|m| !m.is_empty() && m != "NONE") {
            let f = yaml_value(&text, "compression_format").unwrap_or_default();
            bail!(
                "bag {}: rosbag2 compression ({m}, {f}) is not read: decompress it first (`ros2 bag convert`)",
                path.display()
            );
        }
        // The files the metadata lists are the bag; another storage file beside them (a
        // recording moved in, an old split) is not part of it.
        if !text.lines().any(|l| l.trim_end() == "rosbag2_bagfile_information:") {
            bail!(
                "bag {}: {} is not rosbag2 metadata (no rosbag2_bagfile_information at its top)",
                path.display(),
                meta.display()
            );
        }
        let listed = match yaml_file_list(&text) {
            Some(l) if !l.is_empty() => l,
            _ => bail!("bag {}: {} lists no storage files (relative_file_paths)", path.display(), meta.display()),
        };
        let mut files = Vec::new();
        for name in &listed {
            // Older rosbag2 versions wrote the bag folder's name in front: the file name is what
            // counts (as the `rosbags` reader takes it).
            let file = Path::new(name).file_name().map(|n| path.join(n));
            let Some((p, s)) = file.and_then(|p| storage_of(&p).map(|s| (p, s))) else {
                bail!("bag {}: {} lists {name:?}, not an .mcap or .db3 file", path.display(), meta.display())
            };
            if !p.is_file() {
                bail!("bag {}: {} lists {name}, which is missing", path.display(), meta.display());
            }
            if !files.iter().any(|(q, _)| *q == p) {
                files.push((p, s));
            }
        }
        let mut unlisted: Vec<PathBuf> = std::fs::read_dir(path)
            .with_context(|| format!("cannot read {}", path.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| storage_of(p).is_some() && !files.iter().any(|(q, _)| q == p))
            .collect();
        unlisted.sort();
        if files.iter().any(|f| f.1 != files[0].1) {
            bail!("bag {}: lists both .mcap and .db3 files", path.display());
        }
        Ok(Bag { path: path.into(), files, unlisted })
    }

    /// The bag's storage format (every file of a bag has the same).
    pub fn storage(&self) -> Storage {
        self.files[0].1
    }

    /// Every message of the topics named, in each file's order, to `f(topic, type, log time ns,
    /// CDR bytes)`. Each message's encoding must be CDR.
    pub fn for_each(&self, topics: &[&str], f: &mut dyn FnMut(&str, &str, u64, &[u8]) -> Result<()>) -> Result<()> {
        for (p, s) in &self.files {
            match s {
                Storage::Mcap => mcap_messages(p, topics, f),
                Storage::Sqlite3 => sqlite_messages(p, topics, f),
            }
            .with_context(|| format!("bag file {}", p.display()))?;
        }
        Ok(())
    }

    /// The topics, their types and message counts (all files together). Reads every message of
    /// an MCAP file, so a truncated file is found here.
    pub fn topics(&self) -> Result<Vec<Topic>> {
        let mut all: BTreeMap<String, Topic> = BTreeMap::new();
        let mut add = |name: &str, ty: &str, n: u64| -> Result<()> {
            let t = all.entry(name.to_string()).or_insert_with(|| Topic { name: name.into(), type_name: ty.into(), messages: 0 });
            if t.type_name != ty {
                bail!("topic {name} has two types, {} and {ty}", t.type_name);
            }
            t.messages += n;
            Ok(())
        };
        for (p, s) in &self.files {
            match s {
                Storage::Mcap => {
                    let buf = read_all(p)?;
                    let mut ch: BTreeMap<u16, (String, String, u64)> = BTreeMap::new();
                    for m in mcap::MessageStream::new(&buf).with_context(|| format!("bag file {}", p.display()))? {
                        let m = m.map_err(|e| truncated(p, e))?;
                        let e = ch.entry(m.channel.id).or_insert_with(|| {
                            (m.channel.topic.clone(), m.channel.schema.as_ref().map_or(String::new(), |s| s.name.clone()), 0)
                        });
                        e.2 += 1;
                    }
                    // Channels without messages still name their topics.
                    if let Ok(Some(sum)) = mcap::Summary::read(&buf) {
                        for c in sum.channels.values() {
                            ch.entry(c.id).or_insert_with(|| {
                                (c.topic.clone(), c.schema.as_ref().map_or(String::new(), |s| s.name.clone()), 0)
                            });
                        }
                    }
                    for (_, (name, ty, n)) in ch {
                        add(&name, &ty, n)?;
                    }
                }
                Storage::Sqlite3 => {
                    let db = open_db(p)?;
                    let mut q = db
                        .prepare("SELECT t.name, t.type, (SELECT COUNT(*) FROM messages m WHERE m.topic_id = t.id) FROM topics t")
                        .map_err(|e| not_a_bag(p, e))?;
                    let rows = q
                        .query_map([], |r| Ok((r.get::<_, String>(0)?, r.get::<_, String>(1)?, r.get::<_, i64>(2)?)))
                        .map_err(|e| not_a_bag(p, e))?;
                    for r in rows {
                        let (name, ty, n) = r.map_err(|e| not_a_bag(p, e))?;
                        add(&name, &ty, n.max(0) as u64)?;
                    }
                }
            }
        }
        Ok(all.into_values().collect())
    }
}

fn read_all(p: &Path) -> Result<Vec<u8>> {
    std::fs::read(p).with_context(|| format!("cannot read {}", p.display()))
}

fn truncated(p: &Path, e: mcap::McapError) -> anyhow::Error {
    anyhow::anyhow!("bag file {} is damaged or truncated: {e}", p.display())
}

fn not_a_bag(p: &Path, e: rusqlite::Error) -> anyhow::Error {
    anyhow::anyhow!("bag file {} is not a readable rosbag2 SQLite3 file: {e}", p.display())
}

fn open_db(p: &Path) -> Result<rusqlite::Connection> {
    rusqlite::Connection::open_with_flags(p, rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY | rusqlite::OpenFlags::SQLITE_OPEN_NO_MUTEX)
        .map_err(|e| not_a_bag(p, e))
}

fn mcap_messages(p: &Path, topics: &[&str], f: &mut dyn FnMut(&str, &str, u64, &[u8]) -> Result<()>) -> Result<()> {
    let buf = read_all(p)?;
    for m in mcap::MessageStream::new(&buf).map_err(|e| truncated(p, e))? {
        let m = m.map_err(|e| truncated(p, e))?;
        if !topics.contains(&m.channel.topic.as_str()) {
            continue;
        }
        if m.channel.message_encoding != "cdr" {
            bail!("topic {}: message encoding {:?}, not cdr", m.channel.topic, m.channel.message_encoding);
        }
        let ty = m.channel.schema.as_ref().map_or("", |s| s.name.as_str());
        f(&m.channel.topic, ty, m.log_time, &m.data)?;
    }
    Ok(())
}

fn sqlite_messages(p: &Path, topics: &[&str], f: &mut dyn FnMut(&str, &str, u64, &[u8]) -> Result<()>) -> Result<()> {
    let db = open_db(p)?;
    let mut ids: BTreeMap<i64, (String, String)> = BTreeMap::new();
    {
        let mut q = db.prepare("SELECT id, name, type, serialization_format FROM topics").map_err(|e| not_a_bag(p, e))?;
        let rows = q
            .query_map([], |r| Ok((r.get::<_, i64>(0)?, r.get::<_, String>(1)?, r.get::<_, String>(2)?, r.get::<_, String>(3)?)))
            .map_err(|e| not_a_bag(p, e))?;
        for r in rows {
            let (id, name, ty, fmt) = r.map_err(|e| not_a_bag(p, e))?;
            if topics.contains(&name.as_str()) {
                if fmt != "cdr" {
                    bail!("topic {name}: serialization format {fmt:?}, not cdr");
                }
                ids.insert(id, (name, ty));
            }
        }
    }
    let mut q = db
        .prepare("SELECT topic_id, timestamp, data FROM messages ORDER BY timestamp, id")
        .map_err(|e| not_a_bag(p, e))?;
    let mut rows = q.query([]).map_err(|e| not_a_bag(p, e))?;
    while let Some(r) = rows.next().map_err(|e| not_a_bag(p, e))? {
        let id: i64 = r.get(0).map_err(|e| not_a_bag(p, e))?;
        let Some((name, ty)) = ids.get(&id) else { continue };
        let t: i64 = r.get(1).map_err(|e| not_a_bag(p, e))?;
        let data = r.get_ref(2).map_err(|e| not_a_bag(p, e))?.as_blob().map_err(|e| anyhow::anyhow!("topic {name}: message data is not a blob: {e}"))?;
        f(name, ty, t.max(0) as u64, data)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metadata_keys_and_file_order() {
        let y = "rosbag2_bagfile_information:\n  version: 5\n  compression_format: \"\"\n  compression_mode: \"\"\n";
        assert_eq!(yaml_value(y, "compression_mode").as_deref(), Some(""));
        assert_eq!(yaml_value(y, "version").as_deref(), Some("5"));
        let block = "rosbag2_bagfile_information:\n  relative_file_paths:\n  - b_0.mcap\n  - 'b_1.mcap'\n  starting_time: 0\n";
        assert_eq!(yaml_file_list(block), Some(vec!["b_0.mcap".into(), "b_1.mcap".into()]));
        let deeper = "rosbag2_bagfile_information:\n  relative_file_paths:\n    - x/b_0.db3\n  version: 4\n";
        assert_eq!(yaml_file_list(deeper), Some(vec!["x/b_0.db3".into()]));
        assert_eq!(yaml_file_list("relative_file_paths: [a.mcap, \"b.mcap\"]"), Some(vec!["a.mcap".into(), "b.mcap".into()]));
        assert_eq!(yaml_file_list("version: 5\n"), None);
    }

    #[test]
    fn a_missing_bag_or_a_folder_without_metadata_is_refused() {
        let d = tempfile::tempdir().unwrap();
        assert!(Bag::open(&d.path().join("nope")).unwrap_err().to_string().contains("does not exist"));
        assert!(Bag::open(d.path()).unwrap_err().to_string().contains("metadata.yaml"));
        std::fs::write(d.path().join("metadata.yaml"), "compression_mode: FILE\ncompression_format: zstd\n").unwrap();
        assert!(Bag::open(d.path()).unwrap_err().to_string().contains("compression"));
    }
}
