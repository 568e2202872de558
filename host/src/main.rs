//! `deltaz`: the command-line front end. The subcommands are in `deltaz_host::commands`.
use clap::Parser;
use std::process::ExitCode;

/// deltaz: structured-light measurement (camera + dot projector).
#[derive(Parser)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: deltaz_host::commands::Command,
}

/// The default action for SIGPIPE, as Unix tools have: `deltaz ... | head` then ends quietly
/// when the reader closes the pipe, where Rust's runtime (which ignores SIGPIPE) would panic in
/// `println!` with "failed printing to stdout".
#[cfg(unix)]
fn default_sigpipe() {
    // SAFETY: called first in `main`, before any other thread exists, and SIG_DFL installs no
    // handler code: it only gives the signal back its default disposition.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

/// Runs the command; any error prints as one `error: ...` chain (never a backtrace, whatever
/// RUST_BACKTRACE says) and exits with 1, like a bad command line.
fn main() -> ExitCode {
    #[cfg(unix)]
    {
        default_sigpipe();
        // Before any other thread starts: an interrupt removes the temporary files of outputs.
        deltaz_host::io::atomic::remove_temporaries_on_signals();
    }
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            let _ = e.print();
            return if e.use_stderr() {
                ExitCode::FAILURE
            } else {
                ExitCode::SUCCESS
            };
        }
    };
    match cli.command.exec() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
