//! Seed 002 (work in progress).
use crate::{Error, Result};

#[derive(Debug, clap::Args)]
pub struct RotaryArgs {}

pub fn run(_args: &RotaryArgs) -> Result<()> {
    Err(Error::Usage("jdbb rotary: in progress".into()))
}
