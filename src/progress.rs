//! Progress bars of the stages: drawn on stderr when it is a terminal, unless the caller hides
//! them (`timesift run --quiet`), which it says through the project it hands over.

use std::io::IsTerminal;

use indicatif::{ProgressBar, ProgressStyle};

/// Whether the stages of a run draw progress bars.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Progress {
    /// Bars on stderr when it is a terminal.
    #[default]
    OnTerminal,
    /// No bars (`timesift run --quiet`).
    Hidden,
}

/// A progress bar for one epoch of a stage on a terminal (hidden otherwise, and when the
/// project's `progress` says so): `what` names the unit counted.
pub(crate) fn progress_bar(
    progress: Progress,
    stage: &str,
    epoch: &str,
    total: u64,
    what: &str,
) -> ProgressBar {
    if progress == Progress::Hidden || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(total);
    if let Ok(style) = ProgressStyle::with_template(&format!(
        "{{prefix}} [{{bar:30}}] {{pos}}/{{len}} {what}, {{eta}} left"
    )) {
        bar.set_style(style.progress_chars("=> "));
    }
    bar.set_prefix(format!("{stage} {epoch}"));
    bar
}
