//! Reading a rosbag2 recording: a bag folder (`metadata.yaml` with `.mcap` or `.db3` files, read in
//! name order) or one `.mcap` / `.db3` file. MCAP through the `mcap` crate, SQLite3 through
//! `rusqlite` (its bundled SQLite). Messages come out raw (CDR bytes) with their topic's type.
use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One topic of a bag.
#[derive(Clone, Debug, PartialEq)]
pub struct Topic {
    pub name: String,
    /// e.g. `sensor_msgs/msg/Image`.
    pub type_name: String,
    pub messages: u64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Storage {
    Mcap,
    Sqlite3,
}

/// An opened bag: its storage files, in order.
#[derive(Clone, Debug)]
pub struct Bag {
    pub path: PathBuf,
    pub files: Vec<(PathBuf, Storage)>,
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

/// A storage file's number in its bag (`name_12.mcap` -> 12), for ordering.
fn file_index(p: &Path) -> (u64, PathBuf) {
    let stem = p.file_stem().and_then(|s| s.to_str()).unwrap_or("");
    let n = stem.rsplit('_').next().and_then(|d| d.parse().ok()).unwrap_or(0);
    (n, p.to_path_buf())
}

impl Bag {
    pub fn open(path: &Path) -> Result<Bag> {
        if path.is_file() {
            let Some(s) = storage_of(path) else {
                bail!("bag {}: not a bag folder, an .mcap or a .db3 file", path.display())
            };
            return Ok(Bag { path: path.into(), files: vec![(path.into(), s)] });
        }
        if !path.is_dir() {
            bail!("bag {} does not exist", path.display());
        }
        let meta = path.join("metadata.yaml");
        if !meta.is_file() {
            bail!("bag {}: no metadata.yaml (a rosbag2 folder has one)", path.display());
        }
        let text = std::fs::read_to_string(&meta).with_context(|| format!("cannot read {}", meta.display()))?;
        // rosbag2's own compression wraps files (.mcap.zstd) or each message; neither is read.
        if let Some(m) = yaml_value(&text, "compression_mode").filter(|m| !m.is_empty() && m != "NONE") {
            let f = yaml_value(&text, "compression_format").unwrap_or_default();
            bail!(
                "bag {}: rosbag2 compression ({m}, {f}) is not read: decompress it first (`ros2 bag convert`)",
                path.display()
            );
        }
        let mut files: Vec<(u64, PathBuf)> = std::fs::read_dir(path)
            .with_context(|| format!("cannot read {}", path.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| storage_of(p).is_some())
            .map(|p| file_index(&p))
            .collect();
        files.sort();
        if files.is_empty() {
            bail!("bag {}: no .mcap or .db3 file in it", path.display());
        }
        let files: Vec<(PathBuf, Storage)> = files.into_iter().map(|(_, p)| {
            let s = storage_of(&p).expect("filtered");
            (p, s)
        }).collect();
        if files.iter().any(|f| f.1 != files[0].1) {
            bail!("bag {}: holds both .mcap and .db3 files", path.display());
        }
        Ok(Bag { path: path.into(), files })
    }

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
        let mut v = vec![file_index(Path::new("b_10.mcap")), file_index(Path::new("b_2.mcap"))];
        v.sort();
        assert_eq!(v[0].1, Path::new("b_2.mcap"));
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
