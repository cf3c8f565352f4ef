//! An MCAP writer for session logs: profile `ros2`, one channel a topic, schemas in
//! `ros2msg` with the full definitions, messages in CDR, zstd chunks with message indexes and a
//! summary (what Foxglove seeks with, and what rosbag2's MCAP storage and `rosbags` read).
//! Written to a temporary file beside the target and renamed over it when finished.
use super::msgs;
use anyhow::{anyhow, bail, Context, Result};
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// An MCAP file being written: one channel per topic, each type's schema once.
pub struct McapLog {
    w: mcap::Writer<BufWriter<std::fs::File>>,
    /// topic -> (channel id, type, messages so far)
    channels: BTreeMap<String, (u16, &'static str, u32)>,
    schemas: BTreeMap<&'static str, u16>,
    path: PathBuf,
    tmp: PathBuf,
    done: bool,
}

impl McapLog {
    /// Starts the file: its folder is made, and it is written to a temporary file beside `path`
    /// until [`McapLog::finish`].
    pub fn create(path: &Path) -> Result<McapLog> {
        if path.is_dir() {
            bail!("cannot write {}: it is a folder", path.display());
        }
        // Its folder is made as every output's is (see `fsio::write_with`).
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot write {}: cannot create {}", path.display(), dir.display()))?;
        }
        let tmp = crate::fsio::temp_beside(path);
        let f = std::fs::File::create(&tmp).with_context(|| format!("cannot write {}", path.display()))?;
        let w = mcap::WriteOptions::new()
            .profile("ros2")
            .library(concat!("msr ", env!("CARGO_PKG_VERSION")))
            .compression(Some(mcap::Compression::Zstd))
            .chunk_size(Some(1 << 20))
            .create(BufWriter::new(f))
            .map_err(|e| anyhow!("cannot write {}: {e}", path.display()))?;
        Ok(McapLog { w, channels: BTreeMap::new(), schemas: BTreeMap::new(), path: path.into(), tmp, done: false })
    }

    /// Writes `msg` of ROS type `type_name` on `topic` at `t_ns` (log and publish time).
    pub fn add<T: Serialize>(&mut self, topic: &str, type_name: &'static str, t_ns: u64, msg: &T) -> Result<()> {
        self.add_raw(topic, type_name, t_ns, &msgs::encode(msg)?)
    }

    /// As [`McapLog::add`], the message already encoded.
    pub fn add_raw(&mut self, topic: &str, type_name: &'static str, t_ns: u64, data: &[u8]) -> Result<()> {
        let id = match self.channels.get(topic) {
            Some(&(id, ty, _)) if ty == type_name => id,
            Some((_, ty, _)) => bail!("topic {topic} is a {ty}, not a {type_name}"),
            None => {
                let schema = match self.schemas.get(type_name) {
                    Some(&s) => s,
                    None => {
                        let def = msgs::definition(type_name).ok_or_else(|| anyhow!("no definition of {type_name}"))?;
                        let s = self.w.add_schema(type_name, "ros2msg", def.as_bytes()).map_err(|e| self.err(e))?;
                        self.schemas.insert(type_name, s);
                        s
                    }
                };
                let id = self.w.add_channel(schema, topic, "cdr", &BTreeMap::new()).map_err(|e| self.err(e))?;
                self.channels.insert(topic.into(), (id, type_name, 0));
                id
            }
        };
        let seq = {
            let c = self.channels.get_mut(topic).expect("added above");
            c.2 += 1;
            c.2
        };
        let h = mcap::records::MessageHeader { channel_id: id, sequence: seq, log_time: t_ns, publish_time: t_ns };
        self.w.write_to_known_channel(&h, data).map_err(|e| self.err(e))
    }

    fn err(&self, e: mcap::McapError) -> anyhow::Error {
        anyhow!("cannot write {}: {e}", self.path.display())
    }

    /// Messages written so far, per topic.
    pub fn counts(&self) -> BTreeMap<String, u32> {
        self.channels.iter().map(|(t, c)| (t.clone(), c.2)).collect()
    }

    /// Writes the summary and renames the file into place.
    pub fn finish(mut self) -> Result<()> {
        self.w.finish().map_err(|e| self.err(e))?;
        self.done = true;
        std::fs::rename(&self.tmp, &self.path).with_context(|| format!("cannot write {}", self.path.display()))
    }
}

impl Drop for McapLog {
    fn drop(&mut self) {
        if !self.done {
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

/// A grey image as `sensor_msgs/msg/Image` (mono8).
pub fn mono8(t_ns: u64, frame_id: &str, w: u32, h: u32, data: Vec<u8>) -> msgs::Image {
    msgs::Image {
        header: msgs::Header { stamp: msgs::Time::from_ns(t_ns), frame_id: frame_id.into() },
        height: h,
        width: w,
        encoding: "mono8".into(),
        is_bigendian: 0,
        step: w,
        data,
    }
}

/// Joint angles (radians, one per name) as a `sensor_msgs/msg/JointState` without speeds or
/// efforts.
pub fn joint_state(t_ns: u64, names: &[&str], position: &[f64]) -> msgs::JointState {
    msgs::JointState {
        header: msgs::Header { stamp: msgs::Time::from_ns(t_ns), frame_id: String::new() },
        name: names.iter().map(|s| s.to_string()).collect(),
        position: position.to_vec(),
        velocity: Vec::new(),
        effort: Vec::new(),
    }
}

/// Any serializable value (the board's status) as a `diagnostic_msgs/msg/DiagnosticArray` of
/// one status whose values are the value's fields, flattened (`host_link.crc_errors`).
pub fn diagnostics<T: Serialize>(t_ns: u64, name: &str, message: &str, level: u8, v: &T) -> Result<msgs::DiagnosticArray> {
    fn flatten(prefix: &str, v: &serde_json::Value, out: &mut Vec<msgs::KeyValue>) {
        match v {
            serde_json::Value::Object(o) => {
                for (k, v) in o {
                    let key = if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") };
                    flatten(&key, v, out);
                }
            }
            serde_json::Value::String(s) => out.push(msgs::KeyValue { key: prefix.into(), value: s.clone() }),
            other => out.push(msgs::KeyValue { key: prefix.into(), value: other.to_string() }),
        }
    }
    let mut values = Vec::new();
    flatten("", &serde_json::to_value(v)?, &mut values);
    Ok(msgs::DiagnosticArray {
        header: msgs::Header { stamp: msgs::Time::from_ns(t_ns), frame_id: String::new() },
        status: vec![msgs::DiagnosticStatus {
            level,
            name: name.into(),
            message: message.into(),
            hardware_id: "msr board".into(),
            values,
        }],
    })
}

/// The board's detection (blob box, centroid, label).
pub const RED: msgs::Color = msgs::Color { r: 1.0, g: 0.1, b: 0.1, a: 1.0 };
/// The mark's true box (sim), and a recorded frame's label.
pub const GREEN: msgs::Color = msgs::Color { r: 0.1, g: 0.9, b: 0.2, a: 1.0 };
/// The face crop's box.
pub const GREY: msgs::Color = msgs::Color { r: 0.6, g: 0.6, b: 0.6, a: 1.0 };
/// Fully transparent: no fill.
pub const CLEAR: msgs::Color = msgs::Color { r: 0.0, g: 0.0, b: 0.0, a: 0.0 };

/// An inclusive pixel box `[x0, y0, x1, y1]` as a closed outline around its pixels.
pub fn box_outline(t_ns: u64, b: [f64; 4], color: msgs::Color) -> msgs::PointsAnnotation {
    let [x0, y0, x1, y1] = b;
    let p = |x, y| msgs::Point2 { x, y };
    msgs::PointsAnnotation {
        timestamp: msgs::Time::from_ns(t_ns),
        r#type: 2,
        points: vec![p(x0, y0), p(x1 + 1.0, y0), p(x1 + 1.0, y1 + 1.0), p(x0, y1 + 1.0)],
        outline_color: color,
        outline_colors: Vec::new(),
        fill_color: CLEAR,
        thickness: 1.0,
    }
}

/// A filled circle of `diameter` pixels centred on pixel (`x`, `y`).
pub fn circle(t_ns: u64, x: f64, y: f64, diameter: f64, color: msgs::Color) -> msgs::CircleAnnotation {
    msgs::CircleAnnotation {
        timestamp: msgs::Time::from_ns(t_ns),
        // Pixel centres are at +0.5 in Foxglove's image coordinates.
        position: msgs::Point2 { x: x + 0.5, y: y + 0.5 },
        diameter,
        thickness: 1.0,
        fill_color: color,
        outline_color: color,
    }
}

/// A label at (`x`, `y`) in image pixels, 10 px high, on a half-transparent black box.
pub fn text(t_ns: u64, x: f64, y: f64, s: &str, color: msgs::Color) -> msgs::TextAnnotation {
    msgs::TextAnnotation {
        timestamp: msgs::Time::from_ns(t_ns),
        position: msgs::Point2 { x, y },
        text: s.into(),
        font_size: 10.0,
        text_color: color,
        background_color: msgs::Color { r: 0.0, g: 0.0, b: 0.0, a: 0.5 },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_log_reads_back_with_the_mcap_crate() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("a.mcap");
        let mut log = McapLog::create(&p).unwrap();
        let img = mono8(5, "camera", 3, 2, vec![1, 2, 3, 4, 5, 6]);
        log.add("/camera/image", msgs::IMAGE, 5, &img).unwrap();
        log.add("/joint_states", msgs::JOINT_STATE, 6, &joint_state(6, &["HeadYaw"], &[0.25])).unwrap();
        assert!(log.add("/camera/image", msgs::JOINT_STATE, 7, &joint_state(7, &[], &[])).is_err());
        assert!(!p.exists(), "written beside until finished");
        log.finish().unwrap();
        let buf = std::fs::read(&p).unwrap();
        let msgs: Vec<_> = mcap::MessageStream::new(&buf).unwrap().map(|m| m.unwrap()).collect();
        assert_eq!(msgs.len(), 2);
        assert_eq!(msgs[0].channel.schema.as_ref().unwrap().encoding, "ros2msg");
        assert_eq!(super::msgs::decode::<super::msgs::Image>(&msgs[0].data).unwrap(), img);
        let sum = mcap::Summary::read(&buf).unwrap().unwrap();
        assert_eq!(sum.stats.unwrap().message_count, 2);
        assert!(!sum.chunk_indexes.is_empty());
        assert_eq!(std::fs::read_dir(d.path()).unwrap().count(), 1, "no temporary file left");
    }
}
