//! The stages' errors, grouped by who is at fault: a parameter, the inputs on disk, or a
//! crate the stage called (with what the stage was doing, as [`Error::Context`]).

use std::fmt::Display;

/// An error of a stage. Printed with its sources (`{:#}` of an `anyhow` error), it reads as
/// the command line has always printed it: context first, then each cause.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A parameter is out of range, or contradicts another or what is on disk; the message
    /// names the command line's option.
    #[error("{0}")]
    Parameter(String),
    /// The stage's inputs are missing, stale or do not fit together (an earlier stage has to
    /// run, or run again).
    #[error("{0}")]
    Input(String),
    /// A number over one of the stated limits.
    #[error(transparent)]
    Limit(#[from] tracks::limits::OutOfRange),
    #[error(transparent)]
    Store(#[from] prerender::store::StoreError),
    #[error(transparent)]
    Scene(#[from] prerender::scene::SceneError),
    #[error(transparent)]
    Track(#[from] tracks::TrackError),
    #[error(transparent)]
    Pov(#[from] prerender::pov::PovError),
    #[error(transparent)]
    Slabs(#[from] slabs::SlabsError),
    #[error(transparent)]
    Cull(#[from] occlusion::OcclusionError),
    #[error(transparent)]
    Db(#[from] db::DbError),
    #[error(transparent)]
    Ptm(#[from] codec::ptm::PtmError),
    #[error(transparent)]
    Mesh(#[from] codec::mesh::MeshError),
    #[error(transparent)]
    Baseline(#[from] db::baseline::BaselineError),
    #[error(transparent)]
    Chart(#[from] charts::ChartError),
    #[error(transparent)]
    Io(#[from] std::io::Error),
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// What the stage was doing when `source` happened.
    #[error("{context}")]
    Context {
        context: String,
        #[source]
        source: Box<Error>,
    },
}

/// A stage's result.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// `source`, said to have happened while doing `context`.
    pub fn context(self, context: impl Display) -> Error {
        Error::Context {
            context: context.to_string(),
            source: Box::new(self),
        }
    }
}

/// [`Error::Context`] on results, as `anyhow::Context` does.
pub trait Context<T> {
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

impl<T> Context<T> for Option<T> {
    /// `None` as an [`Error::Input`] saying `context`.
    fn context(self, context: impl Display) -> Result<T> {
        self.ok_or_else(|| Error::Input(context.to_string()))
    }
    fn with_context<D: Display>(self, f: impl FnOnce() -> D) -> Result<T> {
        self.ok_or_else(|| Error::Input(f().to_string()))
    }
}

impl Error {
    /// The message with every cause after it, `: `-separated (what `{:#}` of an `anyhow`
    /// error prints).
    pub fn chain(&self) -> String {
        let mut out = self.to_string();
        let mut source = std::error::Error::source(self);
        while let Some(e) = source {
            out += &format!(": {e}");
            source = e.source();
        }
        out
    }
}

/// An [`Error::Parameter`] from a formatted message.
macro_rules! parameter {
    ($($t:tt)*) => { $crate::error::Error::Parameter(format!($($t)*)) };
}
/// An [`Error::Input`] from a formatted message.
macro_rules! input {
    ($($t:tt)*) => { $crate::error::Error::Input(format!($($t)*)) };
}
pub(crate) use input;
pub(crate) use parameter;
