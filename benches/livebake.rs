//! `cargo bench`: the benches of [`livebake::bench`], the same sections and JSON as
//! `livebake bench`.
//!
//! ```text
//! cargo bench                                  # every section
//! cargo bench -- --only runtime,runtime_real   # some of them
//! cargo bench -- --quick --out bench.json      # a smoke run, written where asked
//! ```
//!
//! Run as a test (`cargo test --benches`, no `--bench` argument from cargo), it checks its
//! arguments and lists the sections without measuring anything.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use livebake::bench::{Narrator, SECTIONS};

/// Arguments after `cargo bench --`.
#[derive(Parser, Debug)]
#[command(name = "livebake-bench")]
struct Args {
    /// Output JSON (default: the target directory's tmp/bench.json).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Only these sections, comma-separated (every one when not given).
    #[arg(long, value_delimiter = ',')]
    only: Vec<String>,
    /// Smaller sample sets and fewer repeats (a smoke run, not a measurement).
    #[arg(long)]
    quick: bool,
    /// Passed by `cargo bench`; without it (`cargo test`) nothing is measured.
    #[arg(long)]
    bench: bool,
}

/// Lines to standard output.
struct Stdout;

impl Narrator for Stdout {
    fn line(&self, line: &str) {
        println!("{line}");
    }
}

fn main() -> ExitCode {
    livebake::bake::memory::return_large_buffers_to_the_system();
    let args = Args::parse();
    if let Err(e) = livebake::bench::check_sections(&args.only) {
        eprintln!("error: {e:#}");
        return ExitCode::FAILURE;
    }
    if !args.bench {
        let names: Vec<&str> = SECTIONS.iter().map(|(name, _)| *name).collect();
        println!("bench sections (run with `cargo bench`): {}", names.join(", "));
        return ExitCode::SUCCESS;
    }
    let out = args.out.unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_TARGET_TMPDIR"), "/bench.json")));
    let livebake = PathBuf::from(env!("CARGO_BIN_EXE_livebake"));
    match livebake::bench::run(&out, &args.only, args.quick, &livebake, &Stdout) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
