//! One module per subcommand.

pub mod bench_viewer;
pub mod build;
pub mod cull;
pub mod demo;
pub mod eval;
pub mod flythrough;
pub mod import_pov;
pub mod load;
pub mod prerender;
pub mod render;
pub mod serve;
pub mod slabs;
pub mod tune;
pub mod verify;
pub mod view;
pub mod walk;

/// A face size option (`--face-size`, `--lowres-face-size`, …): 1 to
/// [`tracks::limits::MAX_FACE_SIZE`] pixels.
pub fn face_size(flag: &str, v: u32) -> anyhow::Result<u32> {
    Ok(tracks::limits::check_u64(flag, v as u64, 1, tracks::limits::MAX_FACE_SIZE as u64)? as u32)
}

/// A count option (frames, segments, samples): 1 to `max`.
pub fn count(flag: &str, v: usize, max: usize) -> anyhow::Result<usize> {
    Ok(tracks::limits::check_u64(flag, v as u64, 1, max as u64)? as usize)
}
