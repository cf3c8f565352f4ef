fn main() -> std::process::ExitCode {
    use std::process::ExitCode;
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
