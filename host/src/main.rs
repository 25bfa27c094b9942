//! `jdbb`: thin entry point. Everything lives in the library; this only parses the command line
//! and turns an error into a friendly report and a nonzero exit code.
use clap::Parser;

fn main() -> std::process::ExitCode {
    let cli = jdbb::cli::Cli::parse();
    match jdbb::cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            let mut source = std::error::Error::source(&e);
            while let Some(s) = source {
                eprintln!("  caused by: {s}");
                source = s.source();
            }
            std::process::ExitCode::from(e.exit_code())
        }
    }
}
