//! `msr record`: head babbling on the robot, into a dataset `msr train` reads (see
//! [`crate::record`]).
use crate::camera::SourceConfig;
use crate::record::{self, RecordConfig};
use anyhow::Result;
use msr_sim::Robot;
use std::path::PathBuf;
use std::time::Duration;

/// `msr record`'s flags: the board's line, the camera, the recording and the outputs.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The board that moves the head.
    #[command(flatten)]
    pub line: super::BoardLine,
    /// The camera is the sim's renderer of this robot (red or skin), at the head angles the
    /// servos report
    #[arg(long, value_name = "ROBOT", conflicts_with = "frames")]
    pub sim: Option<Robot>,
    /// How the light changes over the --sim frames (10 a second of sim time)
    #[arg(long, value_enum, default_value_t = super::light::RunLight::Fixed, requires = "sim")]
    pub light: super::light::RunLight,
    /// The --sim camera's imperfections
    #[command(flatten)]
    pub imperfect: super::imperfect::CameraFlags,
    /// The camera: `-` for a Y4M stream on standard input (e.g. `ffmpeg -f v4l2 -i /dev/video0
    /// -f yuv4mpegpipe -pix_fmt gray -`)
    #[arg(long, value_name = "-", conflicts_with = "camera")]
    pub frames: Option<PathBuf>,
    /// The camera: a V4L2 device (e.g. /dev/video0; Linux), held still once its picture settled
    /// (--camera-hold); the values are stored in dataset.json
    #[arg(long, value_name = "DEV", conflicts_with = "sim")]
    pub camera: Option<PathBuf>,
    /// How a V4L2 camera is held.
    #[command(flatten)]
    pub hold: super::camera_hold::HoldArgs,
    /// Frames to keep
    #[arg(long)]
    pub count: usize,
    /// Output folder (the dataset layout of `msr dataset`)
    #[arg(long)]
    pub out: PathBuf,
    /// Head angles drawn uniformly within +-this, degrees
    #[arg(long, default_value_t = 5.0)]
    pub range_deg: f64,
    /// Seed of the head poses, the train/test split and the --sim frames
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Continue an unfinished recording in --out
    #[arg(long)]
    pub resume: bool,
    /// Record over a finished recording in --out
    #[arg(long)]
    pub force: bool,
    /// Face template (grey PNG, e.g. from `msr template`); default: --out's template.png, or
    /// the sim robot's
    #[arg(long)]
    pub template: Option<PathBuf>,
    /// Share of the frames in the test split
    #[arg(long, default_value_t = 0.2)]
    pub test_fraction: f64,
    /// Longest wait for the board to answer a head pose, milliseconds
    #[arg(long, default_value_t = 5000)]
    pub timeout_ms: u64,
    /// Longest wait for a camera frame, milliseconds
    #[arg(long, default_value_t = 5000)]
    pub frame_timeout_ms: u64,
    /// Also write the recording as an MCAP file (frames, face crops, asked and reported head
    /// angles) for Foxglove or `ros2 bag play`
    #[arg(long, value_name = "FILE")]
    pub mcap: Option<PathBuf>,
    /// Serving the recording live to Foxglove.
    #[command(flatten)]
    pub live: super::live::LiveFlags,
}

/// The library's configuration for these flags; a usage error when no camera is given or the
/// camera flags do not go together.
pub fn config(a: &Args) -> Result<RecordConfig> {
    if a.camera.is_none() {
        a.hold.check_unused()?;
    }
    let source = match (&a.frames, &a.camera, a.sim) {
        (Some(p), _, _) if p.as_os_str() == "-" => SourceConfig::Y4mStdin,
        (Some(p), _, _) => return Err(super::usage(format!("--frames takes `-` (a Y4M stream on standard input), got {}", p.display()))),
        (None, Some(dev), _) => SourceConfig::Camera { dev: dev.clone(), hold: a.hold.hold()? },
        (None, None, Some(robot)) => SourceConfig::Sim {
            robot,
            count: None,
            seed: a.seed,
            mark_from: None,
            light: a.light.into(),
            camera: a.imperfect.imperfections(a.seed),
        },
        (None, None, None) => return Err(super::usage("give a camera: --sim red|skin, --frames - or --camera DEV")),
    };
    let mut c = RecordConfig::new(&a.line.port, source, a.count, &a.out);
    c.baud = a.line.baud;
    c.range_deg = a.range_deg;
    c.seed = a.seed;
    c.resume = a.resume;
    c.force = a.force;
    c.template = a.template.clone();
    c.test_fraction = a.test_fraction;
    c.head_timeout = Duration::from_millis(a.timeout_ms);
    c.frame_timeout = Duration::from_millis(a.frame_timeout_ms);
    c.progress = true;
    c.mcap = a.mcap.clone();
    Ok(c)
}

/// An [`OutError`](record::OutError) in the words of the flags that set the fields.
pub(crate) fn flag_text(e: &record::OutError) -> String {
    use record::OutError as E;
    match e {
        E::NotAFolder(p) => format!("--out {} is a file, not a folder", p.display()),
        E::Finished(p) => format!("{} holds a finished recording (or dataset): --force to record over it", p.display()),
        E::Unfinished(p) => format!("{} holds an unfinished recording: --resume to continue it, --force to start again", p.display()),
        E::NotEmpty(_) => e.to_string(),
        E::BadLog { log, what } => format!("{}: {what}: --force to record again", log.display()),
        E::NoTemplate(p) => format!(
            "no face template: give --template FILE, or make {} with `msr template --frame F --box x0,y0,x1,y1 --out {}`",
            p.display(),
            p.display()
        ),
        E::TooMany { log, frames, count } => format!("{} holds {frames} frames, more than --count {count}", log.display()),
    }
}

/// Records, prints the recording's report as JSON and a summary of what was skipped.
pub fn run(a: Args) -> Result<()> {
    let mut c = config(&a)?;
    c.live = a.live.start(false)?;
    // The banner comes from `record` once the folder, the log, the camera and the port passed.
    let r = record::record(&c);
    if let Some(stats) = a.live.finish(c.live.take()) {
        eprintln!("{stats}");
    }
    let r = r?;
    println!("{}", serde_json::to_string(&r)?);
    eprintln!(
        "recorded {} frames ({} from an earlier run); skipped {} without a face, {} poses not \
         settled; largest pose error {:.3} deg",
        r.frames + r.resumed,
        r.resumed,
        r.skipped_no_face,
        r.skipped_not_settled,
        r.max_pose_error_deg
    );
    Ok(())
}
