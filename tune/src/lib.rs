//! Tuning a walkthrough database: which build configuration is cheapest for an error target.
//!
//! - [`cost`]: what a build costs (CPU seconds of this process and the children it waited
//!   for).

pub mod cost;
