//! A private X server (Xvfb) for the viewer's tests and benches on machines without a
//! display: started on a display number it picks itself (`-displayfd`), killed on drop.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};

#[derive(Debug, thiserror::Error)]
pub enum XvfbError {
    #[error("cannot start Xvfb (Debian package `xvfb`; scripts/test installs it): {0}")]
    Spawn(std::io::Error),
    #[error("Xvfb did not report a display number (it printed {0:?})")]
    NoDisplay(String),
}

pub struct Xvfb {
    child: Child,
    /// `:N`, for `DISPLAY`.
    pub display: String,
}

impl Xvfb {
    /// Starts a 1280×800×24 screen, without TCP.
    pub fn start() -> Result<Xvfb, XvfbError> {
        let mut child = Command::new("Xvfb")
            .args(["-displayfd", "1", "-screen", "0", "1280x800x24", "-nolisten", "tcp"])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .map_err(XvfbError::Spawn)?;
        let mut line = String::new();
        let read = child.stdout.take().map(|out| BufReader::new(out).read_line(&mut line));
        match (read, line.trim().parse::<u32>()) {
            (Some(Ok(_)), Ok(n)) => Ok(Xvfb { child, display: format!(":{n}") }),
            _ => {
                let _ = child.kill();
                let _ = child.wait();
                Err(XvfbError::NoDisplay(line))
            }
        }
    }
}

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
