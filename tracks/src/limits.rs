//! Stated limits on numbers that come from outside (command lines, track and scene files,
//! manifests and tables) and size an allocation or a loop. Every reader checks its values
//! against these before using them and names the value and the limit when one is out of
//! range, so a hostile or mistyped number is a one-line error, never an abort or a run that
//! does not end.
//!
//! The limits are far above what a database of this system needs (a face of 8192 pixels is
//! 400 million pixels per panorama; 100 000 viewpoints at 2 m spacing are 200 km of track)
//! and far below what exhausts a machine.

/// Largest cube-map face, pixels per side (prerender, build, manifests).
pub const MAX_FACE_SIZE: u32 = 8192;
/// Smallest tile, pixels per side (a manifest's tile grid; tiles are powers of two).
pub const MIN_TILE_SIZE: u32 = 4;
/// Most tiles along one side of a face (a manifest's grid: 6 × 512² tiles per slab).
pub const MAX_TILES_PER_SIDE: u32 = 512;
/// Most reference viewpoints on one track (a track's `count` or length / `spacing`).
pub const MAX_VIEWPOINTS: usize = 100_000;
/// Most control points of one track.
pub const MAX_TRACK_POINTS: usize = 100_000;
/// Most tracks in one manifest or track file.
pub const MAX_TRACKS: usize = 1024;
/// Most depth slabs.
pub const MAX_SLABS: usize = 64;
/// Longest text field of a manifest (a track's TOML, the scene name).
pub const MAX_TEXT_BYTES: usize = 1 << 20;
/// Most cells of a track's tile grids: tiles per face grid × slabs × viewpoints (a client
/// indexes every one; 64 Mi cells are a few hundred MiB of index).
pub const MAX_GRID_CELLS: u64 = 1 << 26;
/// Largest `manifest.json` read, bytes (clients and readers refuse larger ones unread).
pub const MAX_MANIFEST_BYTES: u64 = 256 << 20;
/// Largest coordinate or arc length, metres (positions beyond it lose f32 precision on the
/// GPU long before; it also keeps lengths / spacing finite).
pub const MAX_COORDINATE_M: f64 = 1e7;

/// A value out of its stated range: the name of the value, what it was, and the range.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{name} = {value} is out of range: {range}")]
pub struct OutOfRange {
    pub name: String,
    pub value: String,
    pub range: String,
}

impl OutOfRange {
    pub fn new(name: impl Into<String>, value: impl ToString, range: impl Into<String>) -> Self {
        OutOfRange {
            name: name.into(),
            value: value.to_string(),
            range: range.into(),
        }
    }
}

/// `value` when it lies in `min..=max`, else an error naming `name` and the range.
pub fn check_u64(name: &str, value: u64, min: u64, max: u64) -> Result<u64, OutOfRange> {
    if (min..=max).contains(&value) {
        Ok(value)
    } else {
        Err(OutOfRange::new(name, value, format!("{min} to {max}")))
    }
}

/// `value` when it is a finite number in `min..=max`, else an error naming `name`, the range
/// and, for NaN and infinities, that the value must be a finite number.
pub fn check_f64(name: &str, value: f64, min: f64, max: f64) -> Result<f64, OutOfRange> {
    if value.is_finite() && value >= min && value <= max {
        Ok(value)
    } else {
        Err(OutOfRange::new(
            name,
            value,
            format!("a finite number from {min} to {max}"),
        ))
    }
}

/// A face size and tile size that make a grid within the limits: face in
/// 1..=[`MAX_FACE_SIZE`], tile a power of two from [`MIN_TILE_SIZE`] (or the face size,
/// when smaller), at most [`MAX_TILES_PER_SIDE`] tiles per side.
pub fn check_grid(face_size: u64, tile_size: u64) -> Result<(), OutOfRange> {
    check_u64("face_size", face_size, 1, MAX_FACE_SIZE as u64)?;
    let min_tile = (MIN_TILE_SIZE as u64).min(face_size.next_power_of_two());
    if !tile_size.is_power_of_two() || tile_size < min_tile {
        return Err(OutOfRange::new(
            "tile_size",
            tile_size,
            format!("a power of two from {min_tile}"),
        ));
    }
    let per_side = face_size.div_ceil(tile_size);
    if per_side > MAX_TILES_PER_SIDE as u64 {
        return Err(OutOfRange::new(
            "face_size / tile_size",
            per_side,
            format!("at most {MAX_TILES_PER_SIDE} tiles per side"),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_in_range_pass_and_others_name_the_value_and_the_range() {
        assert_eq!(check_u64("n", 5, 1, 10), Ok(5));
        let e = check_u64("face_size", 4_000_000_000, 1, 8192).unwrap_err();
        assert_eq!(
            e.to_string(),
            "face_size = 4000000000 is out of range: 1 to 8192"
        );
        assert!(check_f64("speed", f64::NAN, 0.01, 1000.0).is_err());
        assert!(check_f64("speed", f64::INFINITY, 0.01, 1000.0)
            .unwrap_err()
            .to_string()
            .contains("finite"));
        assert_eq!(check_f64("speed", 1.5, 0.01, 1000.0), Ok(1.5));
    }

    #[test]
    fn grids_need_a_power_of_two_tile_and_few_enough_tiles() {
        assert!(check_grid(192, 32).is_ok());
        assert!(check_grid(1, 1).is_ok());
        assert!(check_grid(2, 2).is_ok());
        assert!(check_grid(0, 16).is_err());
        assert!(check_grid(65536, 16).is_err());
        assert!(check_grid(192, 24).is_err());
        assert!(check_grid(192, 2).is_err());
        assert!(check_grid(8192, 8).is_err());
        assert!(check_grid(8192, 16).is_ok());
    }
}
