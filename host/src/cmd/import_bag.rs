//! `msr import-bag`: a rosbag2 recording (MCAP or SQLite3) into a dataset `msr train` reads (see
//! [`crate::rosbag::import`]).
use crate::rosbag::import::{self, ImportConfig};
use anyhow::{bail, Result};
use std::path::PathBuf;

/// `msr import-bag`'s flags: the bag, its topics and joint names, the template, the output and
/// what frames to skip.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The bag: a rosbag2 folder (metadata.yaml with .mcap or .db3 files), or one .mcap or .db3
    pub bag: PathBuf,
    /// Camera topic: sensor_msgs/msg/Image (mono8, rgb8, bgr8, yuv422/uyvy, yuv422_yuy2/yuyv) or
    /// sensor_msgs/msg/CompressedImage (jpeg, png)
    #[arg(long)]
    pub image_topic: String,
    /// Joint topic: sensor_msgs/msg/JointState
    #[arg(long)]
    pub joints_topic: String,
    /// The head's yaw and pitch joints as the JointState messages name them
    #[arg(long, default_value = "HeadYaw,HeadPitch", value_name = "YAW,PITCH")]
    pub joint_names: String,
    /// Face template (grey PNG, e.g. from `msr template`)
    #[arg(long)]
    pub template: PathBuf,
    /// Output folder (new or empty; the dataset layout of `msr record`)
    #[arg(long)]
    pub out: PathBuf,
    /// Skip images taken while a head joint moved faster than this, degrees per second
    #[arg(long, default_value_t = 5.0)]
    pub max_head_speed_deg_s: f64,
    /// Skip images without a joint state this close before and after their stamp, milliseconds
    #[arg(long, default_value_t = 100.0)]
    pub max_joint_gap_ms: f64,
    /// Share of the frames in the test split
    #[arg(long, default_value_t = 0.2)]
    pub test_fraction: f64,
    /// Seed of the split
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// An [`UnnamedJoints`](crate::rosbag::import::UnnamedJoints) in the words of the flag.
pub(crate) fn flag_text(e: &crate::rosbag::import::UnnamedJoints) -> String {
    let [yaw, pitch] = &e.names;
    format!(
        "no message on {} names both {yaw} and {pitch} (names seen: {}): give --joint-names YAW,PITCH",
        e.topic, e.seen
    )
}

/// Parses `--joint-names YAW,PITCH`: two different, non-empty names.
pub fn joint_names(s: &str) -> Result<[String; 2]> {
    match s.split(',').map(str::trim).collect::<Vec<_>>().as_slice() {
        [y, p] if !y.is_empty() && !p.is_empty() && y != p => Ok([y.to_string(), p.to_string()]),
        _ => bail!("--joint-names takes two different names YAW,PITCH, got {s:?}"),
    }
}

/// The library's configuration for these flags (a bad `--joint-names` is an error).
pub fn config(a: &Args) -> Result<ImportConfig> {
    let mut c = ImportConfig::new(&a.bag, &a.image_topic, &a.joints_topic, &a.template, &a.out);
    c.joint_names = joint_names(&a.joint_names)?;
    c.max_speed = a.max_head_speed_deg_s.to_radians();
    c.max_gap_ns = (a.max_joint_gap_ms * 1e6).round() as u64;
    c.test_fraction = a.test_fraction;
    c.seed = a.seed;
    c.progress = true;
    Ok(c)
}

/// Imports the bag, prints the import's report as JSON and a summary of what was skipped.
pub fn run(a: Args) -> Result<()> {
    let c = config(&a)?;
    let r = import::import(&c)?;
    // Said after the import, so that a refusal stays one line.
    if let Ok(bag) = crate::rosbag::read::Bag::open(&a.bag) {
        for p in &bag.unlisted {
            eprintln!("not read: {} (the bag's metadata.yaml does not list it)", p.display());
        }
    }
    println!("{}", serde_json::to_string(&r)?);
    eprintln!(
        "imported {} of {} images into {} ({} train, {} test) in {:.1} s; skipped {} taken while the head \
         moved faster than {} deg/s, {} without a joint state within {} ms, {} with a joint state that is not a \
         number, {} damaged{}, {} without a face",
        r.frames,
        r.images,
        a.out.display(),
        r.train,
        r.test,
        r.seconds,
        r.skipped_moving,
        a.max_head_speed_deg_s,
        r.skipped_no_joint_state,
        a.max_joint_gap_ms,
        r.skipped_invalid_joint_state,
        r.skipped_damaged,
        r.first_damage.as_ref().map_or(String::new(), |d| format!(" (the first: {d})")),
        r.skipped_no_face
    );
    Ok(())
}
