//! `livebake bench`: the benches of [`livebake::bench`] behind the command's progress display,
//! timing this binary where a section runs whole commands.

use std::path::Path;

use anyhow::{Context, Result};

use super::progress::Ui;

impl livebake::bench::Narrator for Ui {
    fn line(&self, line: &str) {
        self.say(line)
    }

    fn status(&self, line: &str) {
        Ui::status(self, line)
    }
}

pub fn run(out: &Path, only: &[String], quick: bool, ui: &Ui) -> Result<()> {
    let livebake = std::env::current_exe().context("cannot find the livebake binary")?;
    livebake::bench::run(out, only, quick, &livebake, ui)
}
