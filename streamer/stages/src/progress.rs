//! How a stage tells what it is doing without printing anything itself: the caller hands it a
//! [`Progress`] (the command line draws bars and writes lines to stderr and stdout; a test
//! passes [`Silent`]).

use std::sync::Arc;

/// What a stage reports while it runs.
pub trait Progress: Send + Sync {
    /// A line of news about the run (stderr on the command line).
    fn message(&self, text: &str);
    /// Text that is the stage's result for a person: tables and summaries (stdout on the
    /// command line), printed as given (with its own line ends).
    fn output(&self, text: &str);
    /// A bar of `len` steps, labelled `label`.
    fn bar(&self, len: u64, label: &str, kind: BarKind) -> Box<dyn Bar>;
}

/// How a bar is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BarKind {
    /// A long run (rendering): elapsed time and an estimate, left drawn when finished.
    Long,
    /// Steps of a stage, cleared when finished.
    Steps,
}

/// One progress bar.
pub trait Bar: Send + Sync {
    /// `n` more steps done.
    fn inc(&self, n: u64);
    /// All steps done.
    fn finish(&self);
}

/// The progress handle stages take: shared, as POV-Ray renders report from a callback that
/// outlives the call.
pub type Reporter = Arc<dyn Progress>;

/// Reports nothing.
#[derive(Clone, Copy, Debug, Default)]
pub struct Silent;

impl Progress for Silent {
    fn message(&self, _: &str) {}
    fn output(&self, _: &str) {}
    fn bar(&self, _: u64, _: &str, _: BarKind) -> Box<dyn Bar> {
        Box::new(Silent)
    }
}

impl Bar for Silent {
    fn inc(&self, _: u64) {}
    fn finish(&self) {}
}

/// A [`Reporter`] that reports nothing.
pub fn silent() -> Reporter {
    Arc::new(Silent)
}
