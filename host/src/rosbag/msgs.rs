//! The ROS 2 messages `msr` reads and writes, as serde structs in field order (CDR has no field
//! names: the order is the format), with their `.msg` definitions for MCAP's `ros2msg` schemas.
//! Encoding is the `cdr-encoding` crate's; this file adds only ROS 2's 4-byte encapsulation
//! header (representation id CDR_LE or CDR_BE, then two option bytes).
use anyhow::{bail, Result};
use serde::{Deserialize, Serialize};

/// `builtin_interfaces/msg/Time`: a time as whole seconds and nanoseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Time {
    /// Whole seconds.
    pub sec: i32,
    /// Nanoseconds past `sec`, below 10^9.
    pub nanosec: u32,
}

impl Time {
    /// A time of `ns` nanoseconds split into seconds and nanoseconds.
    pub fn from_ns(ns: u64) -> Time {
        Time { sec: (ns / 1_000_000_000) as i32, nanosec: (ns % 1_000_000_000) as u32 }
    }
    /// Nanoseconds; `None` for a negative time.
    pub fn to_ns(self) -> Option<u64> {
        (self.sec >= 0).then(|| self.sec as u64 * 1_000_000_000 + self.nanosec as u64)
    }
}

/// `std_msgs/msg/Header`: when the data was taken and in which coordinate frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// When the data was taken.
    pub stamp: Time,
    /// The coordinate frame the data is in (`camera`, `face`; empty for joint states).
    pub frame_id: String,
}

/// `sensor_msgs/msg/Image`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Image {
    /// The frame's time and camera frame.
    pub header: Header,
    /// Rows, pixels.
    pub height: u32,
    /// Columns, pixels.
    pub width: u32,
    /// The pixel layout (`mono8`, `rgb8`, `bgr8`, `yuv422`, ...).
    pub encoding: String,
    /// 1 when multi-byte pixel values are big-endian.
    pub is_bigendian: u8,
    /// Bytes from the start of one row to the start of the next.
    pub step: u32,
    /// The pixels, row by row, `step` bytes a row.
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}

/// `sensor_msgs/msg/CompressedImage`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CompressedImage {
    /// The frame's time and camera frame.
    pub header: Header,
    /// The compression (`jpeg`, `png`, or image_transport's `bgr8; jpeg compressed bgr8`).
    pub format: String,
    /// The compressed file's bytes.
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}

/// `sensor_msgs/msg/JointState`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointState {
    /// When the joints were measured or commanded.
    pub header: Header,
    /// The joints' names; the arrays below, when not empty, hold one value per name.
    pub name: Vec<String>,
    /// Joint angles, radians.
    pub position: Vec<f64>,
    /// Joint speeds, rad/s (empty when not measured).
    pub velocity: Vec<f64>,
    /// Joint torques, N m (empty when not measured).
    pub effort: Vec<f64>,
}

/// `foxglove_msgs/msg/Point2`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Point2 {
    /// Column, pixels from the image's left edge.
    pub x: f64,
    /// Row, pixels from the image's top edge.
    pub y: f64,
}

/// `foxglove_msgs/msg/Color`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Color {
    /// Red, 0 to 1.
    pub r: f64,
    /// Green, 0 to 1.
    pub g: f64,
    /// Blue, 0 to 1.
    pub b: f64,
    /// Opacity, 0 (transparent) to 1.
    pub a: f64,
}

/// `foxglove_msgs/msg/CircleAnnotation`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CircleAnnotation {
    /// The image time the circle belongs to.
    pub timestamp: Time,
    /// The centre, in image pixels.
    pub position: Point2,
    /// Pixels.
    pub diameter: f64,
    /// The outline's width, pixels.
    pub thickness: f64,
    /// The inside's colour.
    pub fill_color: Color,
    /// The outline's colour.
    pub outline_color: Color,
}

/// `foxglove_msgs/msg/PointsAnnotation`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PointsAnnotation {
    /// The image time the points belong to.
    pub timestamp: Time,
    /// 1 points, 2 line loop, 3 line strip, 4 line list.
    pub r#type: u8,
    /// The points, in image pixels.
    pub points: Vec<Point2>,
    /// The colour of every point or line, unless `outline_colors` gives one per point.
    pub outline_color: Color,
    /// One colour per point, or per segment for lines (empty: `outline_color` for all).
    pub outline_colors: Vec<Color>,
    /// The colour inside a closed shape.
    pub fill_color: Color,
    /// Line width or point size, pixels.
    pub thickness: f64,
}

/// `foxglove_msgs/msg/TextAnnotation`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TextAnnotation {
    /// The image time the text belongs to.
    pub timestamp: Time,
    /// The text's bottom-left corner, in image pixels.
    pub position: Point2,
    /// What is written.
    pub text: String,
    /// Pixels.
    pub font_size: f64,
    /// The letters' colour.
    pub text_color: Color,
    /// The colour of the box behind the text.
    pub background_color: Color,
}

/// `foxglove_msgs/msg/ImageAnnotations`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ImageAnnotations {
    /// Circles (a blob's centroid).
    pub circles: Vec<CircleAnnotation>,
    /// Outlines and point sets (the crop box, the mark's and the blob's boxes).
    pub points: Vec<PointsAnnotation>,
    /// Labels.
    pub texts: Vec<TextAnnotation>,
}

/// `diagnostic_msgs/msg/KeyValue`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct KeyValue {
    /// What the value is (`host_link.crc_errors`).
    pub key: String,
    /// The value, as text.
    pub value: String,
}

/// `diagnostic_msgs/msg/DiagnosticStatus`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    /// 0 OK, 1 WARN, 2 ERROR, 3 STALE.
    pub level: u8,
    /// What is reported on (`board status`, a trial's name).
    pub name: String,
    /// A one-line summary (empty when all is well).
    pub message: String,
    /// The device the status is of.
    pub hardware_id: String,
    /// The figures, one per key.
    pub values: Vec<KeyValue>,
}

/// `diagnostic_msgs/msg/DiagnosticArray`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticArray {
    /// When the statuses were taken.
    pub header: Header,
    /// One status per reported part.
    pub status: Vec<DiagnosticStatus>,
}

/// The ROS 2 type name of [`Image`].
pub const IMAGE: &str = "sensor_msgs/msg/Image";
/// The ROS 2 type name of [`CompressedImage`].
pub const COMPRESSED_IMAGE: &str = "sensor_msgs/msg/CompressedImage";
/// The ROS 2 type name of [`JointState`].
pub const JOINT_STATE: &str = "sensor_msgs/msg/JointState";
/// The ROS 2 type name of [`ImageAnnotations`].
pub const IMAGE_ANNOTATIONS: &str = "foxglove_msgs/msg/ImageAnnotations";
/// The ROS 2 type name of [`DiagnosticArray`].
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
