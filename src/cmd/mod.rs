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

/// Largest file a scene names (an OBJ mesh, an image texture) or a scene or track file,
/// bytes.
pub const MAX_ASSET_BYTES: u64 = 256 << 20;

/// A file's bytes, refused unread when larger than [`MAX_ASSET_BYTES`]; the message does not
/// name the file (callers do).
fn read_capped(path: &std::path::Path) -> Result<Vec<u8>, String> {
    use std::io::Read;
    let f = std::fs::File::open(path).map_err(|e| e.to_string())?;
    let len = f.metadata().map_err(|e| e.to_string())?.len();
    if len > MAX_ASSET_BYTES {
        return Err(format!(
            "{len} bytes; files of at most {MAX_ASSET_BYTES} bytes are read"
        ));
    }
    let mut out = Vec::with_capacity(len as usize);
    f.take(MAX_ASSET_BYTES)
        .read_to_end(&mut out)
        .map_err(|e| e.to_string())?;
    Ok(out)
}

/// A file a scene names, within [`MAX_ASSET_BYTES`] (the message names the file).
pub fn read_asset(path: &std::path::Path) -> Result<Vec<u8>, String> {
    read_capped(path).map_err(|e| format!("{}: {e}", path.display()))
}

/// A scene or track file as text, within [`MAX_ASSET_BYTES`].
pub fn read_text(path: &std::path::Path) -> anyhow::Result<String> {
    let bytes = read_capped(path).map_err(anyhow::Error::msg)?;
    String::from_utf8(bytes).map_err(|e| anyhow::anyhow!("not UTF-8 text: {e}"))
}
