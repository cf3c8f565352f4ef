//! The ROS 2 messages `msr` reads and writes, as serde structs in field order (CDR has no field
//! names: the order is the format), with their `.msg` definitions for MCAP's `ros2msg` schemas.
//! Encoding is the `cdr-encoding` crate's; this file adds only ROS 2's 4-byte encapsulation
//! header (representation id CDR_LE or CDR_BE, then two option bytes).
use anyhow::{bail, Result};
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    pub fn from_ns(ns: u64) -> Time {
        Time { sec: (ns / 1_000_000_000) as i32, nanosec: (ns % 1_000_000_000) as u32 }
    }
    /// Nanoseconds; `None` for a negative time.
    pub fn to_ns(self) -> Option<u64> {
        (self.sec >= 0).then(|| self.sec as u64 * 1_000_000_000 + self.nanosec as u64)
    }
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

/// `sensor_msgs/msg/Image`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Image {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub encoding: String,
    pub is_bigendian: u8,
    pub step: u32,
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}

/// `sensor_msgs/msg/CompressedImage`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CompressedImage {
    pub header: Header,
    pub format: String,
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}

/// `sensor_msgs/msg/JointState`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointState {
    pub header: Header,
    pub name: Vec<String>,
    pub position: Vec<f64>,
    pub velocity: Vec<f64>,
    pub effort: Vec<f64>,
}

/// `foxglove_msgs/msg/Point2`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Point2 {
    pub x: f64,
    pub y: f64,
}

/// `foxglove_msgs/msg/Color`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Color {
    pub r: f64,
    pub g: f64,
    pub b: f64,
    pub a: f64,
}

/// `foxglove_msgs/msg/CircleAnnotation`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CircleAnnotation {
    pub timestamp: Time,
    pub position: Point2,
    pub diameter: f64,
    pub thickness: f64,
    pub fill_color: Color,
    pub outline_color: Color,
}

/// `foxglove_msgs/msg/PointsAnnotation`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PointsAnnotation {
    pub timestamp: Time,
    /// 1 points, 2 line loop, 3 line strip, 4 line list.
    pub r#type: u8,
    pub points: Vec<Point2>,
    pub outline_color: Color,
    pub outline_colors: Vec<Color>,
    pub fill_color: Color,
    pub thickness: f64,
}

/// `foxglove_msgs/msg/TextAnnotation`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TextAnnotation {
    pub timestamp: Time,
    pub position: Point2,
    pub text: String,
    pub font_size: f64,
    pub text_color: Color,
    pub background_color: Color,
}

/// `foxglove_msgs/msg/ImageAnnotations`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ImageAnnotations {
    pub circles: Vec<CircleAnnotation>,
    pub points: Vec<PointsAnnotation>,
    pub texts: Vec<TextAnnotation>,
}

/// `diagnostic_msgs/msg/KeyValue`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct KeyValue {
    pub key: String,
    pub value: String,
}

/// `diagnostic_msgs/msg/DiagnosticStatus`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    /// 0 OK, 1 WARN, 2 ERROR, 3 STALE.
    pub level: u8,
    pub name: String,
    pub message: String,
    pub hardware_id: String,
    pub values: Vec<KeyValue>,
}

/// `diagnostic_msgs/msg/DiagnosticArray`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticArray {
    pub header: Header,
    pub status: Vec<DiagnosticStatus>,
}

pub const IMAGE: &str = "sensor_msgs/msg/Image";
pub const COMPRESSED_IMAGE: &str = "sensor_msgs/msg/CompressedImage";
pub const JOINT_STATE: &str = "sensor_msgs/msg/JointState";
pub const IMAGE_ANNOTATIONS: &str = "foxglove_msgs/msg/ImageAnnotations";
pub const DIAGNOSTIC_ARRAY: &str = "diagnostic_msgs/msg/DiagnosticArray";

const TIME_DEF: &str = "int32 sec\nuint32 nanosec\n";
const HEADER_DEF: &str = "builtin_interfaces/Time stamp\nstring frame_id\n";
const POINT2_DEF: &str = "float64 x\nfloat64 y\n";
const COLOR_DEF: &str = "float64 r\nfloat64 g\nfloat64 b\nfloat64 a\n";

/// A definition followed by its dependencies, as ROS 2 concatenates them for a bag: each after a
/// line of 80 `=` and a line `MSG: package/Type`.
fn with_deps(main: &str, deps: &[(&str, &str)]) -> String {
    let mut s = main.to_string();
    for (name, def) in deps {
        s.push_str(&"=".repeat(80));
        s.push_str("\nMSG: ");
        s.push_str(name);
        s.push('\n');
        s.push_str(def);
    }
    s
}

/// The full `ros2msg` definition of one of the types above, dependencies included.
pub fn definition(type_name: &str) -> Option<String> {
    let time = ("builtin_interfaces/Time", TIME_DEF);
    let header = ("std_msgs/Header", HEADER_DEF);
    let point2 = ("foxglove_msgs/Point2", POINT2_DEF);
    let color = ("foxglove_msgs/Color", COLOR_DEF);
    Some(match type_name {
        IMAGE => with_deps(
            "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data\n",
            &[header, time],
        ),
        COMPRESSED_IMAGE => with_deps("std_msgs/Header header\nstring format\nuint8[] data\n", &[header, time]),
        JOINT_STATE => with_deps(
            "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n",
            &[header, time],
        ),
        IMAGE_ANNOTATIONS => with_deps(
            "foxglove_msgs/CircleAnnotation[] circles\nfoxglove_msgs/PointsAnnotation[] points\nfoxglove_msgs/TextAnnotation[] texts\n",
            &[
                (
                    "foxglove_msgs/CircleAnnotation",
                    "builtin_interfaces/Time timestamp\nfoxglove_msgs/Point2 position\nfloat64 diameter\nfloat64 thickness\nfoxglove_msgs/Color fill_color\nfoxglove_msgs/Color outline_color\n",
                ),
                time,
                point2,
                color,
                (
                    "foxglove_msgs/PointsAnnotation",
                    "builtin_interfaces/Time timestamp\nuint8 UNKNOWN=0\nuint8 POINTS=1\nuint8 LINE_LOOP=2\nuint8 LINE_STRIP=3\nuint8 LINE_LIST=4\nuint8 type\nfoxglove_msgs/Point2[] points\nfoxglove_msgs/Color outline_color\nfoxglove_msgs/Color[] outline_colors\nfoxglove_msgs/Color fill_color\nfloat64 thickness\n",
                ),
                (
                    "foxglove_msgs/TextAnnotation",
                    "builtin_interfaces/Time timestamp\nfoxglove_msgs/Point2 position\nstring text\nfloat64 font_size\nfoxglove_msgs/Color text_color\nfoxglove_msgs/Color background_color\n",
                ),
            ],
        ),
        DIAGNOSTIC_ARRAY => with_deps(
            "std_msgs/Header header\ndiagnostic_msgs/DiagnosticStatus[] status\n",
            &[
                header,
                time,
                (
                    "diagnostic_msgs/DiagnosticStatus",
                    "byte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\nbyte level\nstring name\nstring message\nstring hardware_id\ndiagnostic_msgs/KeyValue[] values\n",
                ),
                ("diagnostic_msgs/KeyValue", "string key\nstring value\n"),
            ],
        ),
        _ => return None,
    })
}

/// CDR little-endian with ROS 2's encapsulation header, as `ros2 bag record` stores messages.
pub fn encode<T: Serialize>(msg: &T) -> Result<Vec<u8>> {
    let mut out = vec![0x00, 0x01, 0x00, 0x00];
    cdr_encoding::to_writer::<T, byteorder::LittleEndian, _>(&mut out, msg)?;
    Ok(out)
}

/// Decodes a CDR message with its encapsulation header (either byte order).
pub fn decode<'de, T: Deserialize<'de>>(bytes: &'de [u8]) -> Result<T> {
    if bytes.len() < 4 {
        bail!("a message of {} bytes is shorter than its CDR header", bytes.len());
    }
    let body = &bytes[4..];
    let (v, _) = match bytes[1] {
        0x00 => cdr_encoding::from_bytes::<T, byteorder::BigEndian>(body)?,
        0x01 => cdr_encoding::from_bytes::<T, byteorder::LittleEndian>(body)?,
        r => bail!("CDR representation {:#04x}{:02x} is not plain CDR (XCDR is not read)", bytes[0], r),
    };
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A JointState laid out by hand from the CDR rules (4-byte header; strings as u32 length
    /// with the NUL, then the bytes; sequences as u32 count; f64 aligned to 8 from the body's
    /// start).
    #[test]
    fn joint_state_bytes_follow_the_cdr_layout() {
        let m = JointState {
            header: Header { stamp: Time { sec: 1, nanosec: 2 }, frame_id: "f".into() },
            name: vec!["HeadYaw".into()],
            position: vec![0.5],
            velocity: vec![],
            effort: vec![],
        };
        let b = encode(&m).unwrap();
        let mut want = vec![0, 1, 0, 0];
        want.extend(1i32.to_le_bytes());
        want.extend(2u32.to_le_bytes());
        want.extend(2u32.to_le_bytes());
        want.extend(b"f\0\0\0"); // "f" + NUL, padded to 4
        want.extend(1u32.to_le_bytes());
        want.extend(8u32.to_le_bytes());
        want.extend(b"HeadYaw\0");
        want.extend(1u32.to_le_bytes());
        want.extend([0; 4]); // the f64 aligns to 8 in the body: body offset 36 -> 40
        want.extend(0.5f64.to_le_bytes());
        want.extend(0u32.to_le_bytes());
        want.extend(0u32.to_le_bytes());
        assert_eq!(b, want);
        assert_eq!(decode::<JointState>(&b).unwrap(), m);
    }

    #[test]
    fn every_type_has_a_definition_naming_its_dependencies() {
        for t in [IMAGE, COMPRESSED_IMAGE, JOINT_STATE, IMAGE_ANNOTATIONS, DIAGNOSTIC_ARRAY] {
            let d = definition(t).unwrap();
            assert!(d.contains(&format!("{}\nMSG: builtin_interfaces/Time\n", "=".repeat(80))), "{t}");
        }
        assert!(definition("std_msgs/msg/String").is_none());
        assert!(decode::<Image>(&[0, 1]).is_err());
        assert!(decode::<Image>(&[0, 1, 0, 0, 1]).is_err(), "a truncated body");
    }
}
