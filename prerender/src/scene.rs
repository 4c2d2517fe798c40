//! The scene model: objects (an [`enum Shape`](Shape) and a material), materials with
//! procedural or image textures, a sun, point lights and a sky.
//!
//! A [`Scene`] is built from a [`SceneDesc`] (plain data, validated) or parsed from the TOML
//! scene format ([`Scene::parse_toml`], described in [`crate::parse`]); building prepares the
//! BVH, after which the scene is immutable and shared across threads (`&Scene` is `Sync`).
//! Colours are linear RGB; distances are metres.

use std::sync::Arc;

use glam::DVec3;

use crate::accel::{Accel, Hit};
use crate::geom::Prim;

/// Errors building or parsing a scene; each names the source, and where known the line, the
/// item (`object 3 (box)`, `material "stone"`) and the field.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum SceneError {
    #[error("{}: {message}", at(source_name, *line))]
    Syntax {
        source_name: String,
        line: usize,
        message: String,
    },
    #[error("{}: {item}: field `{field}`: {message}", at(source_name, *line))]
    Invalid {
        source_name: String,
        /// 1-based line of the item, 0 when not known (a scene built in code).
        line: usize,
        item: String,
        field: String,
        message: String,
    },
    #[error("{}: {item}: cannot use `{path}`: {message}", at(source_name, *line))]
    Asset {
        source_name: String,
        line: usize,
        item: String,
        path: String,
        message: String,
    },
}

/// `source:line`, or the source alone when the line is not known (0).
fn at(source_name: &str, line: usize) -> String {
    if line > 0 {
        format!("{source_name}:{line}")
    } else {
        source_name.to_string()
    }
}

/// A triangle mesh: positions and index triples.
#[derive(Clone, Debug, PartialEq)]
pub struct Mesh {
    pub positions: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
}

/// The geometry of an object.
#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    Sphere {
        center: DVec3,
        radius: f64,
    },
    /// Axis-aligned box.
    Box {
        min: DVec3,
        max: DVec3,
    },
    /// Infinite plane through `point` with unit `normal`.
    Plane {
        point: DVec3,
        normal: DVec3,
    },
    /// Capped cylinder (`radius_base == radius_top`) or truncated cone from `base` to `top`.
    Cone {
        base: DVec3,
        top: DVec3,
        radius_base: f64,
        radius_top: f64,
    },
    Triangle {
        a: DVec3,
        b: DVec3,
        c: DVec3,
    },
    Mesh(Arc<Mesh>),
}

impl Shape {
    /// Name used in the TOML format and in errors.
    pub fn kind(&self) -> &'static str {
        match self {
            Shape::Sphere { .. } => "sphere",
            Shape::Box { .. } => "box",
            Shape::Plane { .. } => "plane",
            Shape::Cone {
                radius_base,
                radius_top,
                ..
            } if radius_base == radius_top => "cylinder",
            Shape::Cone { .. } => "cone",
            Shape::Triangle { .. } => "triangle",
            Shape::Mesh(_) => "mesh",
        }
    }

    /// Check sizes and finiteness: `Err((field, message))`.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        fn finite(field: &'static str, v: DVec3) -> Result<(), (&'static str, String)> {
            if v.is_finite() {
                Ok(())
            } else {
                Err((field, format!("must be finite, found {v}")))
            }
        }
        fn size(field: &'static str, r: f64) -> Result<(), (&'static str, String)> {
            if r.is_finite() && r > 0.0 {
                Ok(())
            } else {
                Err((
                    field,
                    format!("must be a positive number of metres, found {r}"),
                ))
            }
        }
        match self {
            Shape::Sphere { center, radius } => {
                finite("center", *center)?;
                size("radius", *radius)
            }
            Shape::Box { min, max } => {
                finite("min", *min)?;
                finite("max", *max)?;
                let ext = *max - *min;
                if ext.min_element() > 0.0 {
                    Ok(())
                } else {
                    Err((
                        "max",
                        format!("box size {ext} must be positive on every axis (max > min)"),
                    ))
                }
            }
            Shape::Plane { point, normal } => {
                finite("point", *point)?;
                finite("normal", *normal)?;
                if normal.length() > 0.0 {
                    Ok(())
                } else {
                    Err(("normal", "must not be zero".into()))
                }
            }
            Shape::Cone {
                base,
                top,
                radius_base,
                radius_top,
            } => {
                finite("base", *base)?;
                finite("top", *top)?;
                if base == top {
                    return Err(("top", "must differ from `base`".into()));
                }
                for (f, r) in [("radius", *radius_base), ("radius_top", *radius_top)] {
                    if !(r.is_finite() && r >= 0.0) {
                        return Err((f, format!("must be >= 0 metres, found {r}")));
                    }
                }
                if *radius_base == 0.0 && *radius_top == 0.0 {
                    return Err(("radius", "both radii are zero".into()));
                }
                Ok(())
            }
            Shape::Triangle { a, b, c } => {
                finite("a", *a)?;
                finite("b", *b)?;
                finite("c", *c)?;
                if (*b - *a).cross(*c - *a).length() > 0.0 {
                    Ok(())
                } else {
                    Err(("c", "triangle has zero area".into()))
                }
            }
            Shape::Mesh(m) => {
                if m.triangles.is_empty() {
                    return Err(("triangles", "mesh has no triangles".into()));
                }
                if let Some(i) = m.positions.iter().position(|p| !p.is_finite()) {
                    return Err(("positions", format!("position {i} is not finite")));
                }
                let n = m.positions.len();
                if let Some(i) = m
                    .triangles
                    .iter()
                    .position(|t| t.iter().any(|&v| v as usize >= n))
                {
                    return Err((
                        "triangles",
                        format!("triangle {i} indexes past the {n} positions"),
                    ));
                }
                Ok(())
            }
        }
    }

    pub(crate) fn push_prims(&self, out: &mut Vec<Prim>) -> usize {
        let before = out.len();
        match self {
            Shape::Sphere { center, radius } => out.push(Prim::Sphere {
                center: *center,
                radius: *radius,
            }),
            Shape::Box { min, max } => out.push(Prim::Box {
                min: *min,
                max: *max,
            }),
            Shape::Plane { point, normal } => out.push(Prim::Plane {
                point: *point,
                normal: normal.normalize(),
            }),
            Shape::Cone {
                base,
                top,
                radius_base,
                radius_top,
            } => out.push(Prim::Cone {
                base: *base,
                axis: (*top - *base).normalize(),
                height: top.distance(*base),
                r0: *radius_base,
                r1: *radius_top,
            }),
            Shape::Triangle { a, b, c } => push_triangle(out, *a, *b, *c),
            Shape::Mesh(m) => {
                for t in &m.triangles {
                    let [a, b, c] = t.map(|i| m.positions[i as usize]);
                    push_triangle(out, a, b, c);
                }
            }
        }
        out.len() - before
    }
}

fn push_triangle(out: &mut Vec<Prim>, a: DVec3, b: DVec3, c: DVec3) {
    let (e1, e2) = (b - a, c - a);
    // Degenerate mesh triangles cover nothing: leave them out.
    if let Some(normal) = e1.cross(e2).try_normalize() {
        out.push(Prim::Triangle { a, e1, e2, normal });
    }
}

/// A linear-RGB image used as a texture (rows from the top).
#[derive(Clone, Debug, PartialEq)]
pub struct TextureImage {
    pub width: u32,
    pub height: u32,
    pub texels: Vec<[f32; 3]>,
}

/// How a material's colour varies over a surface. Procedural textures are functions of the
/// world position projected on the plane most facing the surface normal, `size` metres per
/// repeat.
#[derive(Clone, Debug, PartialEq)]
pub enum Texture {
    Solid,
    Checker {
        color2: DVec3,
        size: f64,
    },
    /// Smooth value noise blending `color` and `color2`.
    Noise {
        color2: DVec3,
        size: f64,
    },
    /// Running-bond bricks of `width × height` with mortar joints of `joint`.
    Bricks {
        mortar: DVec3,
        width: f64,
        height: f64,
        joint: f64,
    },
    /// A facade: windows of `size` on a grid of `spacing`; the horizontal faces stay plain.
    Windows {
        glass: DVec3,
        spacing: [f64; 2],
        size: [f64; 2],
    },
    Image {
        image: Arc<TextureImage>,
        size: f64,
    },
}

/// Surface appearance: a diffuse base colour and a texture.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    pub name: String,
    pub color: DVec3,
    pub texture: Texture,
}

impl Material {
    /// Colours finite and >= 0, texture sizes positive: `Err((field, message))`.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        let colour_ok = |c: DVec3| c.is_finite() && c.min_element() >= 0.0;
        let size_ok = |v: f64| v.is_finite() && v > 0.0;
        if !colour_ok(self.color) {
            return Err((
                "color",
                format!("must be finite and >= 0, found {}", self.color),
            ));
        }
        let bad: Option<(&'static str, String)> = match &self.texture {
            Texture::Checker { size, color2 } | Texture::Noise { size, color2 } => {
                if !size_ok(*size) {
                    Some((
                        "size",
                        format!("must be a positive number of metres, found {size}"),
                    ))
                } else if !colour_ok(*color2) {
                    Some(("color2", format!("must be finite and >= 0, found {color2}")))
                } else {
                    None
                }
            }
            Texture::Bricks {
                mortar,
                width,
                height,
                joint,
            } => {
                if !(size_ok(*width) && size_ok(*height)) {
                    Some((
                        "brick",
                        format!("must be positive, found [{width}, {height}]"),
                    ))
                } else if !size_ok(*joint) {
                    Some(("joint", format!("must be positive, found {joint}")))
                } else if !colour_ok(*mortar) {
                    Some(("mortar", format!("must be finite and >= 0, found {mortar}")))
                } else {
                    None
                }
            }
            Texture::Windows {
                glass,
                spacing,
                size,
            } => {
                if !spacing.iter().all(|v| size_ok(*v)) {
                    Some((
                        "window_spacing",
                        format!("must be positive, found {spacing:?}"),
                    ))
                } else if !size.iter().all(|v| size_ok(*v)) {
                    Some(("window_size", format!("must be positive, found {size:?}")))
                } else if !colour_ok(*glass) {
                    Some(("glass", format!("must be finite and >= 0, found {glass}")))
                } else {
                    None
                }
            }
            Texture::Image { size, .. } => (!size_ok(*size)).then(|| {
                (
                    "size",
                    format!("must be a positive number of metres, found {size}"),
                )
            }),
            Texture::Solid => None,
        };
        bad.map_or(Ok(()), Err)
    }
}

/// Distant light; `direction` points towards the sun.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sun {
    pub direction: DVec3,
    pub color: DVec3,
}

/// Point light with inverse-square falloff (`color` is the irradiance at 1 m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointLight {
    pub position: DVec3,
    pub color: DVec3,
}

/// Sky colour by elevation (also the ambient light, scaled by `ambient`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sky {
    pub zenith: DVec3,
    pub horizon: DVec3,
    pub ground: DVec3,
    pub ambient: f64,
}

impl Default for Sky {
    fn default() -> Self {
        Sky {
            zenith: DVec3::new(0.18, 0.32, 0.62),
            horizon: DVec3::new(0.62, 0.70, 0.80),
            ground: DVec3::new(0.30, 0.28, 0.25),
            ambient: 0.35,
        }
    }
}

/// An object: a shape and the index of its material in [`SceneDesc::materials`].
#[derive(Clone, Debug, PartialEq)]
pub struct Object {
    pub shape: Shape,
    pub material: usize,
}

/// Everything a scene is made of, as plain data.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct SceneDesc {
    pub materials: Vec<Material>,
    pub objects: Vec<Object>,
    pub sun: Option<Sun>,
    pub lights: Vec<PointLight>,
    pub sky: Sky,
}

/// A scene ready for ray queries.
pub struct Scene {
    desc: SceneDesc,
    pub(crate) accel: Accel,
    /// Material index of each primitive in `accel` order.
    pub(crate) prim_material: Vec<u32>,
}

impl std::fmt::Debug for Scene {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Scene")
            .field("objects", &self.desc.objects.len())
            .field("primitives", &self.accel.prims.len())
            .finish()
    }
}

impl Scene {
    /// Validate `desc` and build the acceleration structure. `source_name` labels errors.
    pub fn new(desc: SceneDesc, source_name: &str) -> Result<Scene, SceneError> {
        Scene::new_with_lines(desc, source_name, &[])
    }

    /// As [`Scene::new`], with the source line of each object for error messages.
    pub(crate) fn new_with_lines(
        desc: SceneDesc,
        source_name: &str,
        object_lines: &[usize],
    ) -> Result<Scene, SceneError> {
        let invalid =
            |line: usize, item: String, field: &str, message: String| SceneError::Invalid {
                source_name: source_name.to_string(),
                line,
                item,
                field: field.to_string(),
                message,
            };
        for m in &desc.materials {
            m.validate()
                .map_err(|(field, msg)| invalid(0, format!("material {:?}", m.name), field, msg))?;
        }
        let mut prims = Vec::new();
        let mut prim_object = Vec::new();
        for (i, o) in desc.objects.iter().enumerate() {
            let line = object_lines.get(i).copied().unwrap_or(0);
            let item = format!("object {i} ({})", o.shape.kind());
            o.shape
                .validate()
                .map_err(|(field, msg)| invalid(line, item.clone(), field, msg))?;
            if o.material >= desc.materials.len() {
                return Err(invalid(
                    line,
                    item,
                    "material",
                    format!(
                        "index {} but only {} materials",
                        o.material,
                        desc.materials.len()
                    ),
                ));
            }
            let n = o.shape.push_prims(&mut prims);
            prim_object.extend(std::iter::repeat_n(i as u32, n));
        }
        if let Some(s) = &desc.sun {
            if !(s.direction.is_finite() && s.direction.length() > 0.0 && s.color.is_finite()) {
                return Err(invalid(
                    0,
                    "sun".into(),
                    "direction",
                    "must be finite and non-zero".into(),
                ));
            }
        }
        for (i, l) in desc.lights.iter().enumerate() {
            if !(l.position.is_finite() && l.color.is_finite()) {
                return Err(invalid(
                    0,
                    format!("light {i}"),
                    "position",
                    "must be finite".into(),
                ));
            }
        }
        let (accel, ids) = Accel::build(prims);
        let prim_material = ids
            .iter()
            .map(|&i| desc.objects[prim_object[i as usize] as usize].material as u32)
            .collect();
        let mut desc = desc;
        if let Some(s) = &mut desc.sun {
            s.direction = s.direction.normalize();
        }
        Ok(Scene {
            desc,
            accel,
            prim_material,
        })
    }

    /// The scene's plain description.
    pub fn desc(&self) -> &SceneDesc {
        &self.desc
    }

    /// Number of primitives after meshes are split into triangles.
    pub fn primitive_count(&self) -> usize {
        self.accel.prims.len()
    }

    /// Exact radial distance of the first surface along the unit ray `origin + t·dir` with
    /// `0 <= t < t_max`; `None` if nothing is hit (sky).
    pub fn first_hit(&self, origin: DVec3, dir: DVec3, t_max: f64) -> Option<f64> {
        self.accel.closest(origin, dir, 0.0, t_max).map(|h| h.t)
    }

    /// The first hit with `lo <= t < hi` (with its primitive, for shading).
    pub fn hit_in(&self, origin: DVec3, dir: DVec3, lo: f64, hi: f64) -> Option<Hit> {
        self.accel.closest(origin, dir, lo, hi)
    }

    /// For each interval, the first hit in it, in a single traversal.
    pub fn hits_in_ranges(
        &self,
        origin: DVec3,
        dir: DVec3,
        ranges: &[(f64, f64)],
        out: &mut [Option<Hit>],
    ) {
        self.accel.first_in_each(origin, dir, ranges, out)
    }

    /// Whether any surface lies at `lo <= t < hi` along the unit ray.
    pub fn occluded(&self, origin: DVec3, dir: DVec3, lo: f64, hi: f64) -> bool {
        self.accel.occluded(origin, dir, lo, hi)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one(shape: Shape) -> Scene {
        Scene::new(
            SceneDesc {
                materials: vec![Material {
                    name: "m".into(),
                    color: DVec3::ONE,
                    texture: Texture::Solid,
                }],
                objects: vec![Object { shape, material: 0 }],
                ..Default::default()
            },
            "test",
        )
        .unwrap()
    }

    #[test]
    fn scene_is_sync() {
        fn is_sync<T: Sync + Send>() {}
        is_sync::<Scene>();
    }

    #[test]
    fn negative_and_nan_sizes_are_rejected_naming_the_field() {
        let bad = [
            (
                Shape::Sphere {
                    center: DVec3::ZERO,
                    radius: -1.0,
                },
                "radius",
            ),
            (
                Shape::Sphere {
                    center: DVec3::ZERO,
                    radius: f64::NAN,
                },
                "radius",
            ),
            (
                Shape::Box {
                    min: DVec3::ONE,
                    max: DVec3::ZERO,
                },
                "max",
            ),
            (
                Shape::Sphere {
                    center: DVec3::new(f64::NAN, 0.0, 0.0),
                    radius: 1.0,
                },
                "center",
            ),
        ];
        for (shape, field) in bad {
            let e = Scene::new(
                SceneDesc {
                    materials: vec![Material {
                        name: "m".into(),
                        color: DVec3::ONE,
                        texture: Texture::Solid,
                    }],
                    objects: vec![Object { shape, material: 0 }],
                    ..Default::default()
                },
                "x.toml",
            )
            .unwrap_err();
            match e {
                SceneError::Invalid { field: f, .. } => assert_eq!(f, field),
                other => panic!("{other:?}"),
            }
        }
    }

    #[test]
    fn first_hit_on_a_sphere_and_beyond_it() {
        let s = one(Shape::Sphere {
            center: DVec3::new(0.0, 0.0, -10.0),
            radius: 1.0,
        });
        assert_eq!(
            s.first_hit(DVec3::ZERO, DVec3::NEG_Z, f64::INFINITY),
            Some(9.0)
        );
        assert_eq!(s.first_hit(DVec3::ZERO, DVec3::NEG_Z, 9.0), None);
        assert_eq!(s.first_hit(DVec3::ZERO, DVec3::Z, f64::INFINITY), None);
        // From inside, the exit.
        assert_eq!(
            s.first_hit(DVec3::new(0.0, 0.0, -10.0), DVec3::X, f64::INFINITY),
            Some(1.0)
        );
    }
}
