//! `--camera-hold`, `--settle-frames`, `--camera-controls` on the commands that take `--camera`:
//! how a V4L2 camera's automatic exposure, gain and white balance are held
//! ([`crate::camera::Hold`]).
use crate::camera::Hold;
use anyhow::{Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// What `--camera-hold` does with a V4L2 camera's automatic controls.
#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum HoldMode {
    /// Let them run for --settle-frames frames, then switch them to manual at the values they
    /// reached (or at those of --camera-controls)
    #[default]
    Settle,
    /// Leave them as they are
    Off,
}

/// The camera-hold flags of the commands that take `--camera`.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct HoldArgs {
    /// With --camera: what to do with the camera's automatic exposure, gain and white balance
    /// [default: settle]
    #[arg(long, value_enum, value_name = "MODE", requires = "camera")]
    pub camera_hold: Option<HoldMode>,
    /// With --camera: frames the automatics run for before the camera is held [default: 30]
    #[arg(long, value_name = "N", requires = "camera")]
    pub settle_frames: Option<u32>,
    /// With --camera: hold the camera at a recording's values (its dataset.json, or its folder)
    /// instead of those it settled at
    #[arg(long, value_name = "PATH", requires = "camera")]
    pub camera_controls: Option<PathBuf>,
}

impl HoldArgs {
    /// Refuses these flags without --camera (clap's `requires` lets them pass beside a flag
    /// that conflicts with --camera, such as --frames).
    pub fn check_unused(&self) -> Result<()> {
        if self.camera_hold.is_some() || self.settle_frames.is_some() || self.camera_controls.is_some() {
            return Err(super::usage("--camera-hold, --settle-frames and --camera-controls go with --camera"));
        }
        Ok(())
    }

    /// The hold these flags ask for; a usage error for `--camera-controls` with `--camera-hold
    /// off`, or for a recording that stores no controls.
    pub fn hold(&self) -> Result<Hold> {
        match (self.camera_hold.unwrap_or_default(), &self.camera_controls) {
            (HoldMode::Off, Some(_)) => Err(super::usage("--camera-controls holds the camera: it does not go with --camera-hold off")),
            (HoldMode::Off, None) => Ok(Hold::Off),
            (HoldMode::Settle, p) => Ok(Hold::Settle {
                frames: self.settle_frames.unwrap_or(crate::camera::SETTLE_FRAMES),
                values: p.as_deref().map(stored_controls).transpose()?,
            }),
        }
    }
}

/// The `camera_controls` of a recording's `dataset.json` (`path` is the file or its folder).
pub fn stored_controls(path: &Path) -> Result<BTreeMap<String, i32>> {
    let file = if path.is_dir() { path.join(msr_sim::layout::INDEX_FILE) } else { path.to_path_buf() };
    #[derive(serde::Deserialize)]
    struct Stored {
        camera_controls: Option<BTreeMap<String, i32>>,
    }
    let text = std::fs::read_to_string(&file).with_context(|| format!("--camera-controls: reading {}", file.display()))?;
    let s: Stored = serde_json::from_str(&text).map_err(|e| super::usage(format!("--camera-controls: {} is not a dataset.json: {e}", file.display())))?;
    s.camera_controls.ok_or_else(|| {
        super::usage(format!(
            "--camera-controls: {} stores no camera controls (recorded without --camera, or with --camera-hold off)",
            file.display()
        ))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_recordings_controls_are_read_and_a_dataset_without_them_refused() {
        let d = tempfile::tempdir().unwrap();
        let f = d.path().join("dataset.json");
        std::fs::write(&f, r#"{"robot":"recorded","frames":[],"camera_controls":{"gain":64,"exposure_absolute":156}}"#).unwrap();
        let want: BTreeMap<String, i32> = [("exposure_absolute".to_string(), 156), ("gain".to_string(), 64)].into();
        assert_eq!(stored_controls(d.path()).unwrap(), want);
        assert_eq!(stored_controls(&f).unwrap(), want);
        std::fs::write(&f, r#"{"robot":"red","frames":[]}"#).unwrap();
        let e = stored_controls(&f).unwrap_err().to_string();
        assert!(e.contains("stores no camera controls"), "{e}");
        std::fs::write(&f, "{").unwrap();
        assert!(stored_controls(&f).unwrap_err().to_string().contains("not a dataset.json"));
        let a = HoldArgs { camera_hold: Some(HoldMode::Off), settle_frames: None, camera_controls: Some(f) };
        assert!(a.hold().unwrap_err().to_string().contains("does not go with --camera-hold off"));
        let a = HoldArgs { camera_hold: None, settle_frames: Some(9), camera_controls: None };
        assert_eq!(a.hold().unwrap(), Hold::Settle { frames: 9, values: None });
        assert!(a.check_unused().is_err(), "--settle-frames given");
        let a = HoldArgs { camera_hold: None, settle_frames: None, camera_controls: None };
        a.check_unused().unwrap();
        assert_eq!(a.hold().unwrap(), Hold::Settle { frames: crate::camera::SETTLE_FRAMES, values: None });
    }
}
