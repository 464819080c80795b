//! `cargo bench`: runs `livebake bench` of the binary cargo built beside this target (the
//! sections live in the binary's `cli::bench`), the same sections and JSON.
//!
//! ```text
//! cargo bench                                  # every section
//! cargo bench -- --only runtime,runtime_real   # some of them
//! cargo bench -- --quick --out bench.json      # a smoke run, written where asked
//! ```
//!
//! Run as a test (`cargo test --benches`, no `--bench` argument from cargo), it checks that
//! the binary answers `livebake bench --help` and measures nothing.

use std::path::PathBuf;
use std::process::{Command, ExitCode};

use clap::Parser;

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

fn main() -> ExitCode {
    let args = Args::parse();
    let mut command = Command::new(env!("CARGO_BIN_EXE_livebake"));
    command.arg("bench");
    if !args.bench {
        command.arg("--help");
    } else {
        let out = args.out.unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_TARGET_TMPDIR"), "/bench.json")));
        command.arg("--out").arg(out);
        if !args.only.is_empty() {
            command.arg("--only").arg(args.only.join(","));
        }
        if args.quick {
            command.arg("--quick");
        }
    }
    match command.status() {
        Ok(status) if status.success() => ExitCode::SUCCESS,
        Ok(status) => {
            eprintln!("error: livebake bench {status}");
            ExitCode::FAILURE
        }
        Err(e) => {
            eprintln!("error: cannot run {}: {e}", env!("CARGO_BIN_EXE_livebake"));
            ExitCode::FAILURE
        }
    }
}
