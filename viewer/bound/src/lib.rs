//! The sampling bound between reference samples: the "exact warp".
//!
//! For a view between two reference viewpoints, [`exact_warp`] renders what the two reference
//! panoramas alone can give: full-resolution colour (sRGB 8-bit) and radial depth (metres,
//! `+inf` = sky), no slabs, meshes or codec. It answers how good any two-view renderer can be
//! with these panoramas; the gap between railview and it is the renderer's to close.
//! [`oracle`] picks, per pixel, the better of the two single-reference warps against a ground
//! truth: an upper bound for any weighting of two views (unreachable, since it knows the truth).
//!
//! The recipe (`shared/notes/sampling-bound.md`), all in linear light:
//! 1. Every reference pixel with a finite positive depth is a 3-D point, viewpoint + pixel
//!    direction × depth. Sky (a non-finite depth) is not a point; it is looked up by
//!    direction. A finite depth ≤ 0 is neither (treated as missing).
//! 2. Each point in front of the view camera (view depth ≥ 1 cm) is splatted as its
//!    footprint: the 3-D parallelogram spanned by half the steps to its right and lower
//!    neighbours on the same face when they lie on the same surface (depth ratio within
//!    [`WarpOptions::same_surface`]), projected into the view. To first order that is the
//!    parallelogram spanned by the projected neighbours the note names; projecting the 3-D
//!    footprint stays right near the camera plane, where the screen-space parallelogram of a
//!    surface reaching past the camera smears across the whole view. Where the forward
//!    neighbour is missing (face border, another surface) the backward one spans that axis
//!    instead; an axis with neither (a one-pixel feature), or a footprint crossing the near
//!    limit, makes the splat a square of the pixel's projected size. Every splat is grown by
//!    [`WarpOptions::margin_px`] and always covers the view pixel holding its centre. Inside a
//!    parallelogram the inverse view depth is affine (exact for planes); a square has the
//!    constant view depth of its centre.
//! 3. Each reference is z-buffered on its own (the nearest view depth wins). A pixel's colour
//!    is the reference colour in the direction of the surface point the view pixel sees,
//!    filtered ([`Filter`]) in linear light over the texels on that surface (depth within
//!    `same_surface` of the point's distance; the plain filter where none is), so a colour
//!    across a silhouette in the reference does not bleed in. The two are combined: within
//!    [`WarpOptions::agree`] of the nearer depth they blend with weights `(1 − t, t)`,
//!    otherwise the nearer wins. Where neither has a surface, a reference that sees sky along
//!    the view ray (its nearest depth texel in that direction) gives the sky, filtered over
//!    its sky texels only (both blend); else a hole.
//! 4. [`Bound::filled`]: a hole takes the colour of the farthest of the nearest non-hole
//!    pixels to its left, right, above and below (sky is farthest). A hole never has sky in
//!    its exact direction in either reference, so a sky neighbour's colour is used for it.
//! 5. [`PixelClass`] says which part of a renderer loses the error at each pixel.
//!
//! Where it is only an estimate: the splats approximate each pixel's footprint to first
//! order (on a strongly curved surface, seen magnified, neighbouring footprints can leave
//! gaps wider than the margin, which become holes; silhouettes grow by the margin and the
//! covering rule); the same-surface test is a
//! depth ratio, so steep surfaces can be torn and nearby distinct surfaces joined; the colour
//! lookup filters across silhouettes in the reference; the depth is one ray per reference
//! pixel centre. At the reference samples themselves it is not a floor: the other reference's
//! slightly fat silhouettes can win the depth test. Report the bound between samples.
//!
//! ```
//! use bound::{exact_warp, Reference, WarpOptions, PixelClass};
//! use glam::DVec3;
//! use tracks::{CubeMap, PerspectiveCamera};
//!
//! // Two references 0.5 m apart, each seeing grey surfaces 5 m away in every direction.
//! let color = CubeMap::filled(16, [128u8, 128, 128]);
//! let depth = CubeMap::filled(16, 5.0f32);
//! let a = Reference { position: DVec3::ZERO, color: &color, depth: &depth };
//! let b = Reference { position: DVec3::new(0.5, 0.0, 0.0), color: &color, depth: &depth };
//! let camera = PerspectiveCamera {
//!     position: DVec3::new(0.25, 0.0, 0.0), yaw_deg: 0.0, pitch_deg: 0.0, fov_deg: 60.0,
//!     width: 32, height: 24,
//! };
//! let bound = exact_warp(&a, &b, 0.5, &camera, &WarpOptions::default()).unwrap();
//! assert_eq!(bound.black.len(), 32 * 24);
//! assert!(bound.filled.iter().all(|&c| c == [128, 128, 128]));
//! let holes = bound.class.iter().filter(|&&c| c == PixelClass::Hole).count();
//! assert!(holes < 10);
//! ```

mod compose;
mod sample;
mod splat;
#[cfg(test)]
mod tests;

use glam::DVec3;
use tracks::limits::{check_f64, check_u64, OutOfRange, MAX_COORDINATE_M, MAX_FACE_SIZE};
use tracks::{CubeMap, PerspectiveCamera};

use compose::{compose, Layer};
use splat::{zbuffer, View};

/// Largest view width or height, pixels.
pub const MAX_VIEW_SIZE: u32 = 16384;

/// One reference viewpoint: its position and full-resolution panoramas.
#[derive(Clone, Copy, Debug)]
pub struct Reference<'a> {
    pub position: DVec3,
    /// sRGB 8-bit colour.
    pub color: &'a CubeMap<[u8; 3]>,
    /// Radial depth, metres; `+inf` (any non-finite value) is sky.
    pub depth: &'a CubeMap<f32>,
}

/// How colour is read from a reference panorama (in linear light).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Filter {
    #[default]
    Bilinear,
    /// Catmull-Rom, 4×4 texels (negative lobes clamped at zero).
    Bicubic,
}

/// Parameters of the warp.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WarpOptions {
    /// Growth of every splat, view pixels (closes cracks), 0 to 16.
    pub margin_px: f64,
    /// Neighbours lie on one surface when their depth ratio is within `1 + same_surface`,
    /// 0 to 100.
    pub same_surface: f64,
    /// Two references' surfaces blend when their depths are within `agree` of the nearer
    /// (relative), 0 to 1.
    pub agree: f64,
    pub filter: Filter,
}

impl Default for WarpOptions {
    fn default() -> Self {
        WarpOptions {
            margin_px: 0.05,
            same_surface: 0.30,
            agree: 0.02,
            filter: Filter::Bilinear,
        }
    }
}

/// What a view pixel of the combined warp is, in order of precedence.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PixelClass {
    /// No reference has a surface or sky there (before filling).
    Hole,
    /// No surface; a reference sees sky in that direction.
    Sky,
    /// Only one reference's surface is there: the other has none, or a farther one.
    OneView,
    /// Both agree, and the 3×3 neighbourhood spans a depth ratio above 1.1 (sky counts as
    /// infinitely far, holes are skipped).
    DepthEdge,
    /// Both agree, smooth depth around.
    Interior,
}

/// The warped view, row-major from the top.
#[derive(Clone, Debug, PartialEq)]
pub struct Bound {
    pub width: u32,
    pub height: u32,
    /// Holes left black: what the panoramas alone give.
    pub black: Vec<[u8; 3]>,
    /// Holes filled from the farther side.
    pub filled: Vec<[u8; 3]>,
    pub class: Vec<PixelClass>,
}

/// Why no warp was computed: every case is a parameter out of its stated range.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum BoundError {
    #[error(transparent)]
    OutOfRange(#[from] OutOfRange),
    #[error("reference {reference}: colour faces are {color} pixels, depth faces {depth}")]
    FaceSizeMismatch {
        reference: &'static str,
        color: u32,
        depth: u32,
    },
    #[error("the truth has {got} pixels, the view {expected}")]
    TruthSize { expected: usize, got: usize },
}

fn check_position(name: &str, p: DVec3) -> Result<(), OutOfRange> {
    for (axis, v) in ["x", "y", "z"].iter().zip(p.to_array()) {
        check_f64(
            &format!("{name}.{axis}"),
            v,
            -MAX_COORDINATE_M,
            MAX_COORDINATE_M,
        )?;
    }
    Ok(())
}

fn check_reference(name: &'static str, r: &Reference) -> Result<(), BoundError> {
    check_position(&format!("reference {name} position"), r.position)?;
    let (color, depth) = (r.color.face_size(), r.depth.face_size());
    check_u64(
        &format!("reference {name} face size"),
        color.into(),
        1,
        MAX_FACE_SIZE.into(),
    )?;
    if color != depth {
        return Err(BoundError::FaceSizeMismatch {
            reference: name,
            color,
            depth,
        });
    }
    Ok(())
}

fn check_inputs(
    refs: &[(&'static str, &Reference)],
    camera: &PerspectiveCamera,
    opts: &WarpOptions,
) -> Result<(), BoundError> {
    for (name, r) in refs {
        check_reference(name, r)?;
    }
    let max_view = MAX_VIEW_SIZE.into();
    check_u64("camera width", camera.width.into(), 1, max_view)?;
    check_u64("camera height", camera.height.into(), 1, max_view)?;
    check_position("camera position", camera.position)?;
    check_f64("camera fov_deg", camera.fov_deg, 0.01, 179.0)?;
    check_f64("camera yaw_deg", camera.yaw_deg, -1e6, 1e6)?;
    check_f64("camera pitch_deg", camera.pitch_deg, -1e6, 1e6)?;
    check_f64("margin_px", opts.margin_px, 0.0, 16.0)?;
    check_f64("same_surface", opts.same_surface, 0.0, 100.0)?;
    check_f64("agree", opts.agree, 0.0, 1.0)?;
    Ok(())
}

/// The exact warp of two references into `camera`; `t` is the position weight of `b` along
/// the segment (0 at `a`, 1 at `b`).
pub fn exact_warp(
    a: &Reference,
    b: &Reference,
    t: f64,
    camera: &PerspectiveCamera,
    opts: &WarpOptions,
) -> Result<Bound, BoundError> {
    check_inputs(&[("a", a), ("b", b)], camera, opts)?;
    check_f64("t", t, 0.0, 1.0)?;
    let view = View::new(camera);
    let (za, zb) = rayon::join(|| zbuffer(&view, a, opts), || zbuffer(&view, b, opts));
    let layers = [
        Layer {
            reference: a,
            z: &za,
            weight: 1.0 - t,
        },
        Layer {
            reference: b,
            z: &zb,
            weight: t,
        },
    ];
    Ok(compose(&view, &layers, opts))
}

/// The warp of one reference alone (holes black and filled, classes without `OneView`).
pub fn single_warp(
    r: &Reference,
    camera: &PerspectiveCamera,
    opts: &WarpOptions,
) -> Result<Bound, BoundError> {
    check_inputs(&[("a", r)], camera, opts)?;
    let view = View::new(camera);
    let z = zbuffer(&view, r, opts);
    let layer = Layer {
        reference: r,
        z: &z,
        weight: 1.0,
    };
    Ok(compose(&view, &[layer], opts))
}

/// Per pixel, whichever single-reference warp (holes filled) is closer to `truth` (squared
/// error of the sRGB bytes; `a` on ties): an upper bound for any weighting of two views.
pub fn oracle(
    a: &Reference,
    b: &Reference,
    camera: &PerspectiveCamera,
    opts: &WarpOptions,
    truth: &[[u8; 3]],
) -> Result<Vec<[u8; 3]>, BoundError> {
    check_inputs(&[("a", a), ("b", b)], camera, opts)?;
    let expected = camera.width as usize * camera.height as usize;
    if truth.len() != expected {
        return Err(BoundError::TruthSize {
            expected,
            got: truth.len(),
        });
    }
    let (wa, wb) = rayon::join(
        || single_warp(a, camera, opts),
        || single_warp(b, camera, opts),
    );
    let (wa, wb) = (wa?, wb?);
    let err = |p: [u8; 3], q: [u8; 3]| -> u32 {
        (0..3)
            .map(|k| (p[k] as i32 - q[k] as i32).pow(2) as u32)
            .sum()
    };
    Ok(truth
        .iter()
        .zip(wa.filled.iter().zip(&wb.filled))
        .map(|(&t, (&pa, &pb))| if err(pb, t) < err(pa, t) { pb } else { pa })
        .collect())
}
