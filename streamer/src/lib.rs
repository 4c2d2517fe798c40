//! streamer (under construction)
