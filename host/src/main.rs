use clap::Parser;

fn main() -> std::process::ExitCode {
    let cli = msr_host::cmd::Cli::parse();
    match msr_host::cmd::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            // One clear line (with its causes), never a panic trace.
            eprintln!("msr: error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
