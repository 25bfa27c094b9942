//! `jdbb`: thin entry point. Everything lives in the library; this only parses the command line
//! and turns an error into a friendly report and a nonzero exit code. Nothing here panics on a
//! failing standard error (`2>/dev/full`, a closed pipe), and a panic anywhere below becomes exit
//! 1 with a request to report it, after temporary outputs are removed.
use clap::Parser;

use jdbb::cli::output::note;

/// Exit code of a command that ended on a bug (a panic).
const EXIT_BUG: u8 = 1;

fn main() -> std::process::ExitCode {
    std::panic::set_hook(Box::new(|info| {
        note(&format!(
            "error: jdbb stopped on an internal error (a bug): {info}\n  \
             nothing half-written was left in place. Please report it with the command line you \
             ran and jdbb --version ({}) at the project's issue tracker",
            env!("CARGO_PKG_VERSION")
        ));
        jdbb::fsio::remove_staged();
    }));
    let cli = jdbb::cli::Cli::parse();
    let outcome = std::panic::catch_unwind(move || {
        // For the test of this very hook (host/tests/careless_user.rs): a panic on request.
        if std::env::var_os("JDBB_PANIC_FOR_TEST").is_some() {
            panic!("JDBB_PANIC_FOR_TEST is set");
        }
        jdbb::cli::run(cli)
    });
    match outcome {
        Ok(Ok(())) => std::process::ExitCode::SUCCESS,
        Ok(Err(e)) => {
            let message = e.to_string();
            note(&format!("error: {message}"));
            // Each cause once: a cause whose text the message already carries is not repeated.
            let mut source = std::error::Error::source(&e);
            while let Some(s) = source {
                let text = s.to_string();
                if !message.contains(&text) {
                    note(&format!("  caused by: {text}"));
                }
                source = s.source();
            }
            std::process::ExitCode::from(e.exit_code())
        }
        Err(_) => std::process::ExitCode::from(EXIT_BUG),
    }
}
