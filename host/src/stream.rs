//! TEMPORARY placeholder: being written now (serial streaming). Do not build on this file's contents.
use crate::Result;
#[derive(Debug, clap::Args)]
pub struct LiveArgs {
    #[arg(long)]
    pub port: String,
}
pub fn devices() -> Result<()> {
    Err(crate::Error::Usage("devices: not yet".into()))
}
pub fn live(_a: &LiveArgs) -> Result<()> {
    Err(crate::Error::Usage("live: not yet".into()))
}
