//! A drawn frame as plain data, shared by the GPU renderer ([`crate::gpu`]) and its CPU
//! reference ([`crate::cpu`]), which must not depend on each other.

/// A rendered frame: sRGB RGBA8, rows from the top; alpha 0 marks hole pixels.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    pub width: u32,
    pub height: u32,
    pub rgba: Vec<u8>,
}

impl Frame {
    /// Fraction of pixels that no view covers.
    pub fn hole_fraction(&self) -> f64 {
        let n = (self.width as usize * self.height as usize).max(1);
        self.rgba.chunks(4).filter(|p| p[3] == 0).count() as f64 / n as f64
    }

    /// Pixels no view covered: holes and pixels filled from the farther side (alpha below
    /// 255; `FILLED_ALPHA` of `render.wgsl` for the filled).
    pub fn uncovered_fraction(&self) -> f64 {
        let n = (self.width as usize * self.height as usize).max(1);
        self.rgba.chunks(4).filter(|p| p[3] < 255).count() as f64 / n as f64
    }

    /// Whether pixel `i` (row-major) was filled from the farther side.
    pub fn is_filled(&self, i: usize) -> bool {
        self.rgba.get(4 * i + 3).is_some_and(|a| *a > 0 && *a < 255)
    }

    /// The frame as PNG bytes (RGBA; alpha 0 marks holes).
    pub fn png(&self) -> Result<Vec<u8>, image::ImageError> {
        let mut bytes = Vec::new();
        image::write_buffer_with_format(
            &mut std::io::Cursor::new(&mut bytes),
            &self.rgba,
            self.width,
            self.height,
            image::ExtendedColorType::Rgba8,
            image::ImageFormat::Png,
        )?;
        Ok(bytes)
    }
}
