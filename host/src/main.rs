fn main() -> std::process::ExitCode {
    use std::process::ExitCode;
    quiet_on_closed_stdout();
    let cli = match msr_host::cmd::parse_from(std::env::args_os()) {
        Ok(c) => c,
        Err(e) => {
            use clap::error::ErrorKind;
            if matches!(e.kind(), ErrorKind::DisplayHelp | ErrorKind::DisplayVersion
                | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand)
            {
                e.exit();
            }
            // One line naming the problem, exit code 2 (usage).
            eprintln!("msr: error: {} (see msr --help)", msr_host::cmd::clap_line(&e));
            return ExitCode::from(2);
        }
    };
    match msr_host::cmd::run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // One clear line (with its causes), never a panic trace.
            eprintln!("msr: error: {}", msr_host::cmd::one_line(&e));
            ExitCode::from(msr_host::cmd::exit_code(&e))
        }
    }
}

/// A reader that stops early (`msr status | head -1`) closes standard output: what is left to
/// print is not wanted, so `msr` stops as other tools stop on SIGPIPE (exit 141), not with a
/// panic trace. SIGPIPE itself stays ignored, so that a write to a board's or QEMU's closed
/// socket is still an error `msr` can say.
fn quiet_on_closed_stdout() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let p = info.payload();
        let msg = p.downcast_ref::<String>().map(String::as_str).or_else(|| p.downcast_ref::<&str>().copied()).unwrap_or("");
        if msg.starts_with("failed printing to stdout") && msg.contains("Broken pipe") {
            std::process::exit(141);
        }
        default(info);
    }));
}
