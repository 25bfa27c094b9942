//! `jdbb`: thin entry point. Everything lives in the library; this only parses the command line
//! and turns an error into a friendly report and a nonzero exit code.
use clap::Parser;

fn main() -> std::process::ExitCode {
    let cli = jdbb::cli::Cli::parse();
    match jdbb::cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            let message = e.to_string();
            eprintln!("error: {message}");
            // Each cause once: a cause whose text the message already carries is not repeated.
            let mut source = std::error::Error::source(&e);
            while let Some(s) = source {
                let text = s.to_string();
                if !message.contains(&text) {
                    eprintln!("  caused by: {text}");
                }
                source = s.source();
            }
            std::process::ExitCode::from(e.exit_code())
        }
    }
}
