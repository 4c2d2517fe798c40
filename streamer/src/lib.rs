//! streamer: the PTM codec, the walkthrough database and ACH hints (plus, in progress, the
//! HTTP tile server and client).
//!
//! - [`ptm`]: progressive texture maps — lossless mip levels sent coarse to fine.
//! - [`db`]: the content-addressed database directory (writer, reader, `verify`), the compact
//!   mesh format and ACH (average coverage hints) per track segment.

pub mod db;
pub mod ptm;
