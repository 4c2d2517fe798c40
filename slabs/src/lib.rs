//! slabs (under construction)
