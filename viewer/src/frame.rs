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
}
