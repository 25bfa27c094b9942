//! `jdbb devices`: the serial ports the system knows.
use super::output::print;
use crate::link::stream::list_ports;
use crate::Result;

/// Run `jdbb devices`.
pub fn run() -> Result<()> {
    let ports = list_ports()?;
    let mut s = String::new();
    if ports.is_empty() {
        s += "no serial ports found\n";
    }
    for (name, what) in &ports {
        s += &format!("{name}\t{what}\n");
    }
    s += "note: pseudo-terminals (QEMU's serial port) are not listed: pass the /dev/pts/N path QEMU prints when it starts to --port\n";
    print(&s)
}
