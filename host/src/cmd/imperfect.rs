//! The camera's imperfections as flags (`msr_sim::imperfect::Imperfections`): one definition for
//! the commands that render sim frames (`msr dataset`, `msr mirror-test`, `msr run --sim`,
//! `msr record --sim`) and those that take test frames (`msr eval`, `msr detect`); one range check
//! (in [`super::check`]), in the unit each flag names.
use msr_sim::imperfect::Imperfections;

/// The camera-imperfection flags, each in the unit its help names.
#[derive(clap::Args, Debug, Clone)]
pub struct CameraFlags {
    /// Camera: exposure factor (0.05..=20), on the colour frame before grey (clipped at 255)
    #[arg(long, default_value_t = 1.0)]
    pub exposure: f64,
    /// Camera: tone curve 255 (v/255)^GAMMA (0.2..=5; under 1 brightens the mid-tones)
    #[arg(long, default_value_t = 1.0)]
    pub gamma: f64,
    /// Camera: the colour temperature of the light, K (2000..=12000), against a white balance
    /// set for 5500 K: lower is warmer (green and blue down), higher cooler
    #[arg(long, alias = "color-temperature", default_value_t = 5500.0)]
    pub colour_temperature: f64,
    /// Camera: white balance as gains R,G,B (each 0.25..=4), e.g. 1.15,1,0.85 for a camera
    /// balanced 15 % warm; in place of --colour-temperature
    #[arg(long, value_name = "R,G,B", value_delimiter = ',', conflicts_with = "colour_temperature")]
    pub white_balance: Vec<f64>,
    /// Camera: sensor noise, grey levels sd (0..=64), Gaussian, the same draws on every run
    #[arg(long, default_value_t = 0.0)]
    pub noise: f64,
    /// Camera: defocus, the Gaussian blur's sigma in px (0..=10)
    #[arg(long, default_value_t = 0.0)]
    pub defocus: f64,
    /// Camera: motion blur, px (0..=50) along --motion-angle; in episodes and `--sim` streams,
    /// the smear at the head's default speed (0.83 rad/s), scaled by its speed between frames
    /// and along its direction (a head at rest takes sharp frames)
    #[arg(long, default_value_t = 0.0)]
    pub motion_blur: f64,
    /// Camera: direction of --motion-blur in the image, degrees (0: horizontal, 90: vertical)
    #[arg(long, default_value_t = 0.0)]
    pub motion_angle: f64,
    /// Camera: JPEG quality the frames go through (1..=100), as an MJPEG webcam streams them
    #[arg(long)]
    pub jpeg: Option<i64>,
}

impl Default for CameraFlags {
    /// The flags' own defaults: the calibration camera, no imperfection.
    fn default() -> CameraFlags {
        CameraFlags {
            exposure: 1.0,
            gamma: 1.0,
            colour_temperature: 5500.0,
            white_balance: Vec::new(),
            noise: 0.0,
            defocus: 0.0,
            motion_blur: 0.0,
            motion_angle: 0.0,
            jpeg: None,
        }
    }
}

impl CameraFlags {
    /// The imperfections these flags ask for, the noise drawn from `seed` (checked ranges:
    /// [`super::check`]).
    pub fn imperfections(&self, seed: u64) -> Imperfections {
        Imperfections::NONE
            .with_exposure(self.exposure as f32)
            .with_gamma(self.gamma as f32)
            .with_colour_temperature(self.colour_temperature as f32)
            .with_white_balance(match self.white_balance[..] {
                [r, g, b] => [r as f32, g as f32, b as f32],
                _ => msr_sim::light::tint_of_kelvin(self.colour_temperature as f32),
            })
            .with_noise(self.noise as f32)
            .with_defocus(self.defocus as f32)
            .with_motion(self.motion_blur as f32, self.motion_angle as f32)
            .with_jpeg(self.jpeg.map(|q| q.clamp(1, 100) as u8))
            .with_seed(seed)
    }
}

#[cfg(test)]
mod tests {
    use crate::cmd::{check, exit_code, one_line, parse_from, Command};
    use msr_sim::imperfect::{Imperfections, MotionBlur};

    const ALL: [&str; 16] = [
        "--exposure", "1.3", "--gamma", "0.8", "--colour-temperature", "4675", "--noise", "6",
        "--defocus", "1", "--motion-blur", "5", "--motion-angle", "90", "--jpeg", "50",
    ];

    /// Each command line with the flags after its own required ones.
    fn lines() -> Vec<Vec<&'static str>> {
        [
            vec!["msr", "dataset", "--out", "/tmp/x"],
            vec!["msr", "mirror-test", "--model", "m"],
            vec!["msr", "run", "--port", "p", "--model", "m", "--sim", "red"],
            vec!["msr", "record", "--port", "p", "--sim", "red", "--count", "3", "--out", "/tmp/x"],
            vec!["msr", "eval", "--model", "m", "--data", "d"],
            vec!["msr", "detect", "--model", "m", "--image", "i.png", "--head-yaw", "0", "--head-pitch", "0"],
        ]
        .into()
    }

    fn flags_of(c: &Command) -> &super::CameraFlags {
        match c {
            Command::Dataset(a) => &a.imperfect,
            Command::MirrorTest(a) => &a.imperfect,
            Command::Run(a) => &a.imperfect,
            Command::Record(a) => &a.imperfect,
            Command::Eval(a) => &a.imperfect,
            Command::Detect(a) => &a.imperfect,
            _ => unreachable!(),
        }
    }

    #[test]
    fn every_command_takes_the_same_flags_to_the_same_model() {
        let want = Imperfections::NONE
            .with_exposure(1.3)
            .with_gamma(0.8)
            .with_colour_temperature(4675.0)
            .with_noise(6.0)
            .with_defocus(1.0)
            .with_motion(5.0, 90.0)
            .with_jpeg(Some(50))
            .with_seed(7);
        for line in lines() {
            let cli = parse_from(line.iter().chain(ALL.iter()).copied()).unwrap_or_else(|e| panic!("{line:?}: {e}"));
            assert_eq!(flags_of(&cli.command).imperfections(7), want, "{line:?}");
            // Without the flags: nothing changes.
            let plain = parse_from(line.iter().copied()).unwrap();
            assert!(flags_of(&plain.command).imperfections(7).is_none(), "{line:?}");
            // The library's default is what the command line gives without flags.
            assert_eq!(format!("{:?}", flags_of(&plain.command)), format!("{:?}", super::CameraFlags::default()));
        }
        let wb = parse_from(["msr", "eval", "--model", "m", "--data", "d", "--white-balance", "1.15,1,0.85"]).unwrap();
        assert_eq!(flags_of(&wb.command).imperfections(0).white_balance, [1.15, 1.0, 0.85]);
        assert!(parse_from(["msr", "eval", "--model", "m", "--data", "d", "--white-balance", "1,1,1", "--colour-temperature", "5000"]).is_err());
        let m = parse_from(["msr", "dataset", "--out", "o", "--motion-blur", "3"]).unwrap();
        assert_eq!(flags_of(&m.command).imperfections(0).motion, MotionBlur { length_px: 3.0, angle_deg: 0.0 });
    }

    #[test]
    fn a_bad_value_is_one_line_naming_its_flag_with_exit_2() {
        let cases: [(&str, &str, &str); 16] = [
            ("--exposure", "0", "got 0"),
            ("--exposure", "-1", "got -1"),
            ("--exposure", "NaN", "got NaN"),
            ("--exposure", "inf", "got inf"),
            ("--exposure", "21", "got 21"),
            ("--exposure", "1e308", "got 1e308"),
            ("--noise", "-1", "got -1"),
            ("--noise", "NaN", "got NaN"),
            ("--noise", "inf", "got inf"),
            ("--noise", "1e308", "got 1e308"),
            ("--noise", "65", "got 65"),
            ("--gamma", "0", "got 0"),
            ("--colour-temperature", "100", "got 100"),
            ("--defocus", "11", "got 11"),
            ("--motion-blur", "-2", "got -2"),
            ("--jpeg", "101", "got 101"),
        ];
        for line in lines() {
            for (flag, v, says) in cases {
                let cli = parse_from(line.iter().chain([flag, v].iter()).copied()).unwrap_or_else(|e| panic!("{line:?} {flag} {v}: {e}"));
                let e = check::check(&cli.command).expect_err(&format!("{line:?} {flag} {v}"));
                let msg = one_line(&e);
                assert_eq!(exit_code(&e), 2, "{msg}");
                assert!(msg.starts_with(&format!("{flag} must be")) && msg.ends_with(says), "{line:?}: {msg}");
                assert!(!msg.contains('\n'));
            }
        }
        let cli = parse_from(["msr", "eval", "--model", "m", "--data", "d", "--white-balance", "1,0,1"]).unwrap();
        let e = check::check(&cli.command).unwrap_err();
        assert_eq!((exit_code(&e), one_line(&e).as_str()), (2, "--white-balance must be a number in 0.25..=4 (a gain), got 0"));
        let cli = parse_from(["msr", "eval", "--model", "m", "--data", "d", "--white-balance", "1,1"]).unwrap();
        assert_eq!(exit_code(&check::check(&cli.command).unwrap_err()), 2);
    }

    #[test]
    fn the_camera_flags_need_the_sim_on_run_and_record() {
        for line in [
            vec!["msr", "run", "--port", "p", "--model", "m", "--frames", "-", "--gamma", "0.8"],
            vec!["msr", "record", "--port", "p", "--frames", "-", "--count", "3", "--out", "/tmp/x", "--jpeg", "50"],
        ] {
            let cli = parse_from(line.iter().copied()).unwrap();
            let e = check::check(&cli.command).unwrap_err();
            assert_eq!(exit_code(&e), 2);
            assert!(one_line(&e).contains("give --sim"), "{}", one_line(&e));
        }
    }
}
