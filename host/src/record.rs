//! TEMPORARY placeholder: being written now (recording). Do not build on this file's contents.
use crate::Result;
#[derive(Debug, clap::Args)]
pub struct RecordArgs {
    #[arg(long)]
    pub port: String,
}
pub fn record(_a: &RecordArgs) -> Result<()> {
    Err(crate::Error::Usage("record: not yet".into()))
}
