//! The `livebake` command. With no arguments it views the bundled default scene (headless
//! without a display: the runtime for 3 s into `./out`).

mod cli;

use std::process::ExitCode;

fn main() -> ExitCode {
    livebake::bake::memory::return_large_buffers_to_the_system();
    // Bad input is an `Err`; a panic can only be a bug. Say so in one line, exit 1 like any
    // other failure, and leave earlier results alone (outputs are written atomically).
    std::panic::set_hook(Box::new(|info| {
        eprintln!("error: internal error, a bug in livebake (please report it): {info}");
    }));
    match std::panic::catch_unwind(cli::run) {
        Ok(Ok(())) => ExitCode::SUCCESS,
        Ok(Err(e)) => match e.downcast_ref::<cli::NotConverged>() {
            // Not a failure: `converge` ran and tells its pipeline the target was not reached.
            Some(not_converged) => {
                eprintln!("{not_converged}");
                ExitCode::from(cli::NotConverged::EXIT_STATUS)
            }
            None => {
                eprintln!("error: {e:#}");
                ExitCode::FAILURE
            }
        },
        Err(_) => ExitCode::FAILURE,
    }
}
