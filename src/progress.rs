//! The stages' progress on the terminal: bars drawn by indicatif on stderr, news on stderr,
//! results on stdout.

use std::sync::Arc;

use indicatif::{ProgressBar, ProgressStyle};
use stages::progress::{Bar, BarKind, Progress, Reporter};

/// Progress on the terminal.
pub struct Terminal;

/// The reporter every command hands to the stages.
pub fn terminal() -> Reporter {
    Arc::new(Terminal)
}

impl Progress for Terminal {
    fn message(&self, text: &str) {
        eprintln!("{text}");
    }

    fn output(&self, text: &str) {
        print!("{text}");
    }

    fn bar(&self, len: u64, label: &str, kind: BarKind) -> Box<dyn Bar> {
        let template = match kind {
            BarKind::Long => "{msg:>14} [{elapsed_precise}] {wide_bar} {pos}/{len} (eta {eta})",
            BarKind::Steps => "{msg} {bar:40} {pos}/{len} {eta}",
        };
        let pb = ProgressBar::new(len);
        pb.set_style(
            ProgressStyle::with_template(template).unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        pb.set_message(label.to_string());
        Box::new(TerminalBar { pb, kind })
    }
}

struct TerminalBar {
    pb: ProgressBar,
    kind: BarKind,
}

impl Bar for TerminalBar {
    fn inc(&self, n: u64) {
        self.pb.inc(n);
    }

    fn finish(&self) {
        match self.kind {
            BarKind::Long => self.pb.finish(),
            BarKind::Steps => self.pb.finish_and_clear(),
        }
    }
}
