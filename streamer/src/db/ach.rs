//! ach
