//! The sweep's errors: a parameter, a stage, the evaluation, the walk, or the files it
//! keeps, with what the sweep was doing ([`Error::Context`]).

use std::fmt::Display;

/// An error of a sweep. Printed with its sources (`{:#}` of an `anyhow` error), it reads as
/// the command line has always printed it: context first, then each cause.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A parameter is out of range or contradicts another; the message names the option.
    #[error("{0}")]
    Parameter(String),
    /// What was measured or kept does not allow a choice (no configuration reaches a
    /// target, a record without a number).
    #[error("{0}")]
    Outcome(String),
    #[error(transparent)]
    Stage(#[from] stages::Error),
    #[error(transparent)]
    View(#[from] viewer::headless::HeadlessError),
    #[error(transparent)]
    Gpu(#[from] viewer::gpu::GpuError),
    #[error(transparent)]
    Walk(#[from] streamer::walk::WalkError),
    #[error(transparent)]
    Server(#[from] streamer::server::ServerError),
    #[error(transparent)]
    Client(#[from] streamer::client::ClientError),
    #[error(transparent)]
    Db(#[from] db::DbError),
    #[error(transparent)]
    Store(#[from] prerender::store::StoreError),
    #[error(transparent)]
    Chart(#[from] charts::ChartError),
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// What the sweep was doing when `source` happened.
    #[error("{context}")]
    Context {
        context: String,
        #[source]
        source: Box<Error>,
    },
}

/// A sweep's result.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// `self`, said to have happened while doing `context`.
    pub fn context(self, context: impl Display) -> Error {
        Error::Context {
            context: context.to_string(),
            source: Box::new(self),
        }
    }
}

/// [`Error::Context`] on results, as `anyhow::Context` does.
pub(crate) trait Context<T> {
    fn context(self, context: impl Display) -> Result<T>;
    fn with_context<D: Display>(self, f: impl FnOnce() -> D) -> Result<T>;
}

impl<T, E: Into<Error>> Context<T> for std::result::Result<T, E> {
    fn context(self, context: impl Display) -> Result<T> {
        self.map_err(|e| e.into().context(context))
    }
    fn with_context<D: Display>(self, f: impl FnOnce() -> D) -> Result<T> {
        self.map_err(|e| e.into().context(f()))
    }
}
