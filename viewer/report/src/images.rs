//! Pictures for the report: the four horizontal faces of a stored cube map laid out as one
//! 360° strip, and plain copies of the plots other stages wrote.

use std::path::Path;

use image::{DynamicImage, GenericImage, GenericImageView, ImageFormat};
use tracks::Face;

use crate::{write_file, ReportError};

/// Faces around the horizon, left to right, so that each face's right edge meets the next
/// face's left edge (see the table in `tracks::cubemap`).
pub const STRIP_FACES: [Face; 4] = [Face::PosX, Face::PosZ, Face::NegX, Face::NegZ];

/// Largest face edge drawn in the report; bigger faces are scaled down.
pub const MAX_STRIP_FACE: u32 = 256;

fn image_error(action: &'static str, path: &Path, error: image::ImageError) -> ReportError {
    ReportError::Image {
        action,
        path: path.to_path_buf(),
        error,
    }
}

/// A stored cube map (`N × 6N`, faces stacked in `Face` order) and its face size `N`.
fn open_cube(cube_png: &Path) -> Result<(DynamicImage, u32), ReportError> {
    let img = image::open(cube_png).map_err(|e| image_error("reading", cube_png, e))?;
    let (w, h) = img.dimensions();
    if w == 0 || h != 6 * w {
        return Err(ReportError::NotACubeMap {
            path: cube_png.to_path_buf(),
            width: w,
            height: h,
        });
    }
    Ok((img, w))
}

/// Read a stored cube map (`N × 6N`, faces stacked in `Face` order) and return the horizon
/// strip (`4N × N`, RGB or RGBA as stored), scaled down to at most [`MAX_STRIP_FACE`] per face.
pub fn horizon_strip(cube_png: &Path) -> Result<DynamicImage, ReportError> {
    let (img, n) = open_cube(cube_png)?;
    let mut strip = match &img {
        DynamicImage::ImageRgba8(_) | DynamicImage::ImageLumaA8(_) => {
            DynamicImage::new_rgba8(4 * n, n)
        }
        _ => DynamicImage::new_rgb8(4 * n, n),
    };
    for (i, face) in STRIP_FACES.iter().enumerate() {
        let view = img.view(0, face.index() as u32 * n, n, n);
        strip
            .copy_from(&*view, i as u32 * n, 0)
            .map_err(|e| image_error("composing the horizon strip of", cube_png, e))?;
    }
    if n > MAX_STRIP_FACE {
        strip = strip.resize_exact(
            4 * MAX_STRIP_FACE,
            MAX_STRIP_FACE,
            image::imageops::FilterType::Triangle,
        );
    }
    Ok(strip)
}

/// One face of a stored cube map (`N × 6N`), scaled down to at most [`MAX_STRIP_FACE`].
pub fn cube_face(cube_png: &Path, face: Face) -> Result<DynamicImage, ReportError> {
    let (img, w) = open_cube(cube_png)?;
    let face_img = img.crop_imm(0, face.index() as u32 * w, w, w);
    Ok(if w > MAX_STRIP_FACE {
        face_img.resize_exact(
            MAX_STRIP_FACE,
            MAX_STRIP_FACE,
            image::imageops::FilterType::Triangle,
        )
    } else {
        face_img
    })
}

/// The horizontal face of an RGBA cube map with the most opaque pixels (where a far slab
/// has the most to show); `PosX` for an image without alpha or without opaque pixels.
pub fn busiest_face(cube_png: &Path) -> Result<Face, ReportError> {
    let (img, w) = open_cube(cube_png)?;
    if !img.color().has_alpha() {
        return Ok(Face::PosX);
    }
    let rgba = img.to_rgba8();
    let count = |f: Face| {
        let y0 = f.index() as u32 * w;
        (y0..y0 + w)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .filter(|&(x, y)| rgba.get_pixel(x, y)[3] > 0)
            .count()
    };
    Ok(STRIP_FACES
        .iter()
        .copied()
        .max_by_key(|&f| (count(f), std::cmp::Reverse(f.index())))
        .unwrap_or(Face::PosX))
}

/// Write `img` as PNG into `path` (temp file + rename).
pub fn save_png(img: &DynamicImage, path: &Path) -> Result<(), ReportError> {
    let mut bytes = std::io::Cursor::new(Vec::new());
    img.write_to(&mut bytes, ImageFormat::Png)
        .map_err(|e| image_error("encoding", path, e))?;
    write_file(path, bytes.get_ref())
}

/// Copy an image into the report directory after checking that it decodes, so the page never
/// links a broken picture.
pub fn copy_checked(src: &Path, dst: &Path) -> Result<(), ReportError> {
    let bytes = std::fs::read(src).map_err(|e| ReportError::io("reading", src, e))?;
    image::load_from_memory(&bytes).map_err(|e| image_error("decoding", src, e))?;
    write_file(dst, &bytes)
}

/// Copy a plot's SVG into the report directory if there is one (`Ok(false)` if not), after
/// checking that it is an SVG document.
pub fn copy_svg(src: &Path, dst: &Path) -> Result<bool, ReportError> {
    let bytes = match std::fs::read(src) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(false),
        Err(e) => return Err(ReportError::io("reading", src, e)),
    };
    let head = String::from_utf8_lossy(&bytes[..bytes.len().min(256)]).to_string();
    if !(head.trim_start().starts_with("<svg") || head.trim_start().starts_with("<?xml")) {
        return Err(ReportError::NotSvg {
            path: src.to_path_buf(),
        });
    }
    write_file(dst, &bytes)?;
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{Rgb, RgbImage, Rgba, RgbaImage};

    fn tmp(name: &str) -> std::path::PathBuf {
        let d =
            std::env::temp_dir().join(format!("railview-report-img-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn strip_takes_the_horizontal_faces_in_order() {
        let n = 4;
        // Each face filled with its storage index.
        let cube = RgbImage::from_fn(n, 6 * n, |_, y| Rgb([(y / n) as u8 * 10, 0, 0]));
        let dir = tmp("strip");
        let path = dir.join("color.png");
        cube.save(&path).unwrap();
        let strip = horizon_strip(&path).unwrap().to_rgb8();
        assert_eq!(strip.dimensions(), (4 * n, n));
        for (i, face) in STRIP_FACES.iter().enumerate() {
            let px = strip.get_pixel(i as u32 * n + 1, 1);
            assert_eq!(px[0], face.index() as u8 * 10, "strip slot {i}");
        }
    }

    #[test]
    fn strip_keeps_alpha_of_slab_layers() {
        let n = 2;
        let cube = RgbaImage::from_fn(n, 6 * n, |x, _| {
            Rgba([1, 2, 3, if x == 0 { 0 } else { 255 }])
        });
        let dir = tmp("alpha");
        let path = dir.join("slab.png");
        cube.save(&path).unwrap();
        let strip = horizon_strip(&path).unwrap();
        assert!(strip.color().has_alpha());
        assert_eq!(strip.to_rgba8().get_pixel(0, 0)[3], 0);
        assert_eq!(strip.to_rgba8().get_pixel(1, 0)[3], 255);
    }

    #[test]
    fn strip_rejects_an_image_that_is_not_a_cube_map() {
        let dir = tmp("bad");
        let path = dir.join("wide.png");
        RgbImage::new(8, 8).save(&path).unwrap();
        let e = horizon_strip(&path).unwrap_err().to_string();
        assert!(e.contains("N × 6N") && e.contains("8 × 8"), "{e}");
    }

    #[test]
    fn face_crop_and_busiest_face() {
        let n = 3;
        // Only NegX (index 1) and a little of PosZ (index 4) are opaque.
        let cube = RgbaImage::from_fn(n, 6 * n, |x, y| {
            let f = y / n;
            let a = if f == 1 || (f == 4 && x == 0) { 255 } else { 0 };
            Rgba([f as u8, 0, 0, a])
        });
        let dir = tmp("busy");
        let path = dir.join("slab.png");
        cube.save(&path).unwrap();
        assert_eq!(busiest_face(&path).unwrap(), Face::NegX);
        let face = cube_face(&path, Face::PosZ).unwrap().to_rgba8();
        assert_eq!(face.dimensions(), (n, n));
        assert_eq!(face.get_pixel(1, 1)[0], 4);
        // Nothing opaque anywhere: the first horizon face.
        let empty = dir.join("empty.png");
        RgbaImage::new(n, 6 * n).save(&empty).unwrap();
        assert_eq!(busiest_face(&empty).unwrap(), Face::PosX);
    }

    #[test]
    fn big_faces_are_scaled_down() {
        let n = MAX_STRIP_FACE + 2;
        let dir = tmp("big");
        let path = dir.join("big.png");
        RgbImage::new(n, 6 * n).save(&path).unwrap();
        let strip = horizon_strip(&path).unwrap();
        assert_eq!(strip.dimensions(), (4 * MAX_STRIP_FACE, MAX_STRIP_FACE));
    }

    #[test]
    fn copy_refuses_a_broken_image() {
        let dir = tmp("copy");
        let src = dir.join("broken.png");
        std::fs::write(&src, b"\x89PNG\r\n\x1a\nnot really").unwrap();
        let e = copy_checked(&src, &dir.join("out.png")).unwrap_err();
        assert!(format!("{e:#}").contains("broken.png"));
        assert!(!dir.join("out.png").exists());
    }
}
