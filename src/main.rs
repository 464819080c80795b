//! The `livebake` command. With no arguments it views the bundled default scene (headless
//! without a display: the runtime for 3 s into `./out`).

mod cli;

use std::process::ExitCode;

fn main() -> ExitCode {
    return_large_buffers_to_the_system();
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

/// Serves every allocation of 1 MiB or more with its own mapping, unmapped when freed. glibc's
/// default raises that threshold after the first large free (up to 32 MiB), so later buffers
/// of up to 32 MiB come from the heap and, once freed, stay in the resident set: on a
/// 4 M-texel bake that kept ~7 B a texel of freed temporaries resident at the bake's peak,
/// above what the memory estimate counts. Requests this large are few (per-texel and
/// per-pixel arrays, fragment buffers), so a mapping each costs nothing measurable.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn return_large_buffers_to_the_system() {
    // SAFETY: mallopt only sets an allocator parameter; it is called before any other thread
    // exists, and a refusal (return 0) leaves glibc's default in place, which is still correct.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 20);
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn return_large_buffers_to_the_system() {}
