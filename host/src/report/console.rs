//! How a command reports: text for people or one JSON object on stdout; status and progress on
//! stderr unless quiet.

use anyhow::Result;
use std::io::IsTerminal;

/// Where and how results, status lines and progress go.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Output {
    /// The result as one JSON object on stdout (status and progress stay on stderr).
    pub json: bool,
    /// No status lines or progress on stderr (errors are still printed).
    pub quiet: bool,
}

impl Output {
    /// A status line on stderr.
    pub fn status(&self, line: impl std::fmt::Display) {
        if !self.quiet {
            eprintln!("{line}");
        }
    }

    /// The result on stdout: `text` for people, or `json`.
    pub fn result(&self, text: &str, json: &serde_json::Value) -> Result<()> {
        if self.json {
            println!("{}", serde_json::to_string_pretty(json)?);
        } else {
            print!("{text}");
        }
        Ok(())
    }

    /// Progress of a step that may take more than a second: a spinner on a terminal, a plain
    /// line when stderr is not one, nothing when quiet. Finish it with `finish_and_clear`.
    pub fn progress(&self, message: String) -> indicatif::ProgressBar {
        if self.quiet {
            return indicatif::ProgressBar::hidden();
        }
        if !std::io::stderr().is_terminal() {
            eprintln!("{message} ...");
            return indicatif::ProgressBar::hidden();
        }
        let bar = indicatif::ProgressBar::new_spinner().with_message(message);
        bar.enable_steady_tick(std::time::Duration::from_millis(120));
        bar
    }

    /// Progress of `len` items: a bar with the rate on a terminal, one plain line when stderr
    /// is not one, nothing when quiet. Finish it with `finish_and_clear`.
    pub fn counter(&self, message: String, len: u64) -> indicatif::ProgressBar {
        if self.quiet || !std::io::stderr().is_terminal() {
            self.status(format!("{message} ..."));
            return indicatif::ProgressBar::hidden();
        }
        let bar = indicatif::ProgressBar::new(len).with_message(message);
        bar.set_style(
            indicatif::ProgressStyle::with_template("{msg}: {bar:40} {pos}/{len}, {per_sec}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar
    }
}
