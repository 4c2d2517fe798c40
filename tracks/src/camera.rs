//! The perspective camera shared by the ground-truth renderer, the viewer and evaluation.
//!
//! World-relative angles: `yaw = 0` looks along −z, `yaw = 90°` along +x (turning right, seen
//! from above), `pitch > 0` looks up. `fov_deg` is the horizontal field of view. Pixel `(x, y)`
//! has `y` growing downwards; pixel centres at half-integers.

use glam::DVec3;
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PerspectiveCamera {
    pub position: DVec3,
    pub yaw_deg: f64,
    pub pitch_deg: f64,
    /// Horizontal field of view, degrees, in (0, 180).
    pub fov_deg: f64,
    pub width: u32,
    pub height: u32,
}

impl PerspectiveCamera {
    /// Unit viewing direction.
    pub fn forward(&self) -> DVec3 {
        let (y, p) = (self.yaw_deg.to_radians(), self.pitch_deg.to_radians());
        DVec3::new(y.sin() * p.cos(), p.sin(), -y.cos() * p.cos())
    }

    /// Orthonormal `(right, up, forward)`; stays defined looking straight up or down.
    pub fn basis(&self) -> (DVec3, DVec3, DVec3) {
        let f = self.forward();
        let y = self.yaw_deg.to_radians();
        // Right depends on yaw only, so it is well defined at pitch ±90°.
        let r = DVec3::new(y.cos(), 0.0, y.sin());
        let u = r.cross(f);
        (r, u, f)
    }

    /// Unit world direction through continuous pixel position `(x, y)`.
    pub fn ray_dir(&self, x: f64, y: f64) -> DVec3 {
        let (r, u, f) = self.basis();
        let t = (self.fov_deg.to_radians() * 0.5).tan();
        let (w, h) = (self.width.max(1) as f64, self.height.max(1) as f64);
        let sx = (2.0 * x / w - 1.0) * t;
        let sy = (1.0 - 2.0 * y / h) * t * h / w;
        (f + sx * r + sy * u).normalize()
    }

    /// Unit direction through the centre of pixel `(px, py)`.
    pub fn pixel_dir(&self, px: u32, py: u32) -> DVec3 {
        self.ray_dir(px as f64 + 0.5, py as f64 + 0.5)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam(yaw: f64, pitch: f64) -> PerspectiveCamera {
        PerspectiveCamera {
            position: DVec3::ZERO,
            yaw_deg: yaw,
            pitch_deg: pitch,
            fov_deg: 90.0,
            width: 4,
            height: 2,
        }
    }

    #[test]
    fn angles_follow_the_convention() {
        assert!((cam(0.0, 0.0).forward() - DVec3::NEG_Z).length() < 1e-12);
        assert!((cam(90.0, 0.0).forward() - DVec3::X).length() < 1e-12);
        assert!((cam(0.0, 90.0).forward() - DVec3::Y).length() < 1e-12);
    }

    #[test]
    fn basis_is_right_handed_even_looking_straight_down() {
        for (yaw, pitch) in [(0.0, 0.0), (30.0, -90.0), (200.0, 90.0), (45.0, 10.0)] {
            let (r, u, f) = cam(yaw, pitch).basis();
            assert!((r.cross(u) + f).length() < 1e-12, "{yaw} {pitch}");
            assert!(u.is_finite() && (u.length() - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn image_edges_span_the_field_of_view() {
        let c = cam(0.0, 0.0);
        let left = c.ray_dir(0.0, 1.0);
        assert!((left - DVec3::new(-1.0, 0.0, -1.0).normalize()).length() < 1e-12);
        let top = c.ray_dir(2.0, 0.0);
        assert!(top.y > 0.0);
    }
}
