//! viewer (under construction)
