//! `jdbb record`: stream from a device into a CSV file until `--seconds`, Ctrl-C or the device
//! goes away; then a summary. Ending because the device went away is an error (nonzero exit),
//! reported after the file is complete.
use std::path::PathBuf;
use std::time::Instant;

use super::output::emit;
use super::stream_args::StreamArgs;
use crate::link::record::{create_output, record_to, summary, End};
use crate::link::stream::{describe_info, interrupt_flag, Stream};
use crate::{Error, Result};

/// Arguments of `jdbb record`.
#[derive(Debug, Clone, clap::Args)]
pub struct RecordArgs {
    #[command(flatten)]
    pub stream: StreamArgs,
    /// Output CSV file (created or overwritten).
    #[arg(long, short, value_name = "FILE")]
    pub out: PathBuf,
}

/// Run `jdbb record`.
pub fn run(args: &RecordArgs) -> Result<()> {
    args.stream.validate()?;
    let mut file = create_output(&args.out)?;
    let mut stream = match Stream::open(&args.stream.port) {
        Ok(s) => s,
        Err(e) => {
            // Leave no empty recording behind for a port that never opened.
            drop(file);
            let _ = std::fs::remove_file(&args.out);
            return Err(e);
        }
    };
    let interrupted = interrupt_flag();
    args.stream.start(&mut stream)?;
    eprintln!(
        "recording {} to {} ({})",
        args.stream.port,
        args.out.display(),
        match args.stream.seconds {
            Some(s) => format!("{s} s or Ctrl-C"),
            None => "Ctrl-C to stop".into(),
        }
    );
    let t0 = Instant::now();
    let end = record_to(
        &mut stream,
        &mut file,
        &args.out,
        args.stream.deadline(t0),
        &interrupted,
        &mut |info| eprintln!("device: {}", describe_info(info)),
    )?;
    let seconds = t0.elapsed().as_secs_f64();
    args.stream.stop(&mut stream);
    file.sync_data().map_err(|source| Error::File {
        action: "cannot write",
        path: args.out.clone(),
        source,
    })?;
    emit(&format!(
        "recorded {} ({}): {}",
        args.out.display(),
        end.describe(),
        summary(stream.stats(), seconds)
    ))?;
    match end {
        End::Lost(e) => Err(e),
        _ => Ok(()),
    }
}
