//! The TOML scene format, written by hand or emitted by the generators in
//! [`crate::scenes`]. Colours are linear RGB in [0, 1] (light colours may exceed 1), lengths
//! in metres, right-handed with y up.
//!
//! ```toml
//! [sky]                       # all optional
//! zenith = [0.18, 0.32, 0.62]
//! horizon = [0.62, 0.70, 0.80]
//! ground = [0.30, 0.28, 0.25]
//! ambient = 0.35              # sky light on surfaces
//!
//! [sun]                       # optional
//! direction = [0.4, 0.8, 0.3] # towards the sun
//! color = [1.0, 0.95, 0.9]
//!
//! [[light]]                   # point lights, inverse-square falloff
//! position = [0, 3, 0]
//! color = [20, 18, 15]        # irradiance at 1 m
//!
//! [[material]]
//! name = "stone"
//! color = [0.5, 0.48, 0.45]
//! texture = "bricks"          # solid (default) | checker | noise | bricks | windows | image
//! mortar = [0.7, 0.7, 0.68]   # bricks: mortar colour, brick = [w, h], joint
//! brick = [0.4, 0.2]
//! joint = 0.02
//! # checker / noise: color2, size;  windows: glass, window_spacing, window_size;
//! # image: image = "file.png", size (metres per repeat)
//!
//! [[object]]
//! type = "box"                # sphere | box | plane | cylinder | cone | triangle | mesh
//! min = [-1, 0, -1]
//! max = [1, 2, 1]
//! material = "stone"          # optional: a grey default otherwise
//! # sphere: center, radius;  plane: point, normal;  cylinder: base, top, radius;
//! # cone: base, top, radius, radius_top;  triangle: a, b, c;
//! # mesh: positions + triangles (inline), or obj = "file.obj" with optional translate, scale
//!
//! [[track]]                   # optional: tracks, as in `tracks::TrackSet`
//! ```
//!
//! Errors name the source, the line of the offending table, the item and the field.
//! External files (OBJ meshes, PNG images) are read through a loader the caller supplies, so
//! this crate does no file I/O of its own.

use std::collections::HashMap;
use std::fmt::Write as _;
use std::sync::Arc;

use glam::DVec3;
use serde::Deserialize;
use toml::Spanned;

use crate::scene::{
    Material, Mesh, Object, PointLight, Scene, SceneDesc, SceneError, Shape, Sky, Sun, Texture,
    TextureImage,
};
use crate::shade::srgb8_to_linear;

/// Loads an external file named in a scene (relative to the scene file): bytes or a message.
pub type AssetLoader<'a> = &'a dyn Fn(&str) -> Result<Vec<u8>, String>;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileToml {
    sky: Option<SkyToml>,
    sun: Option<Spanned<SunToml>>,
    #[serde(default)]
    light: Vec<Spanned<LightToml>>,
    #[serde(default)]
    material: Vec<Spanned<MaterialToml>>,
    #[serde(default)]
    object: Vec<Spanned<ObjectToml>>,
    /// Tracks are read by [`tracks_from_scene_toml`].
    #[serde(default)]
    #[allow(dead_code)]
    track: Option<toml::Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SkyToml {
    zenith: Option<[f64; 3]>,
    horizon: Option<[f64; 3]>,
    ground: Option<[f64; 3]>,
    ambient: Option<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SunToml {
    direction: [f64; 3],
    color: Option<[f64; 3]>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct LightToml {
    position: [f64; 3],
    color: [f64; 3],
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MaterialToml {
    name: String,
    color: [f64; 3],
    texture: Option<String>,
    color2: Option<[f64; 3]>,
    size: Option<f64>,
    mortar: Option<[f64; 3]>,
    brick: Option<[f64; 2]>,
    joint: Option<f64>,
    glass: Option<[f64; 3]>,
    window_spacing: Option<[f64; 2]>,
    window_size: Option<[f64; 2]>,
    image: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ObjectToml {
    #[serde(rename = "type")]
    kind: String,
    material: Option<String>,
    center: Option<[f64; 3]>,
    radius: Option<f64>,
    radius_top: Option<f64>,
    min: Option<[f64; 3]>,
    max: Option<[f64; 3]>,
    point: Option<[f64; 3]>,
    normal: Option<[f64; 3]>,
    base: Option<[f64; 3]>,
    top: Option<[f64; 3]>,
    a: Option<[f64; 3]>,
    b: Option<[f64; 3]>,
    c: Option<[f64; 3]>,
    positions: Option<Vec<[f64; 3]>>,
    triangles: Option<Vec<[u32; 3]>>,
    obj: Option<String>,
    translate: Option<[f64; 3]>,
    scale: Option<f64>,
}

impl ObjectToml {
    /// Names of the fields that are set.
    fn set_fields(&self) -> Vec<&'static str> {
        let mut v = Vec::new();
        macro_rules! chk {
            ($($f:ident),*) => { $( if self.$f.is_some() { v.push(stringify!($f)); } )* };
        }
        chk!(center, radius, radius_top, min, max, point, normal, base, top, a, b, c);
        chk!(positions, triangles, obj, translate, scale);
        v
    }
}

fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}

fn v3(a: [f64; 3]) -> DVec3 {
    DVec3::from_array(a)
}

impl Scene {
    /// Parse the TOML scene format. Scenes naming external files (OBJ meshes, images) need
    /// [`Scene::parse_toml_with`].
    pub fn parse_toml(text: &str, source_name: &str) -> Result<Scene, SceneError> {
        Scene::parse_toml_with(text, source_name, &|path: &str| {
            Err(format!(
                "external file `{path}`: this scene must be loaded with a file loader"
            ))
        })
    }

    /// Parse the TOML scene format, reading external files through `load`.
    pub fn parse_toml_with(
        text: &str,
        source_name: &str,
        load: AssetLoader<'_>,
    ) -> Result<Scene, SceneError> {
        let (desc, lines) = parse_desc(text, source_name, load)?;
        Scene::new_with_lines(desc, source_name, &lines)
    }
}

/// Largest image texture, pixels per side (the decoder refuses larger ones before
/// allocating them; a texture is kept as linear f32 RGB, 768 MiB at this size).
pub const MAX_TEXTURE_SIZE: u32 = 8192;

/// An image texture's bytes as RGB, within [`MAX_TEXTURE_SIZE`] per side.
fn decode_texture(bytes: &[u8]) -> Result<image::RgbImage, String> {
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_TEXTURE_SIZE);
    limits.max_image_height = Some(MAX_TEXTURE_SIZE);
    let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| format!("not a readable image: {e}"))?;
    reader.limits(limits);
    Ok(reader
        .decode()
        .map_err(|e| format!("not a readable image (at most {MAX_TEXTURE_SIZE} px per side): {e}"))?
        .to_rgb8())
}

/// The `[[track]]` tables of a scene file, if it has any.
pub fn tracks_from_scene_toml(
    text: &str,
    source_name: &str,
) -> Result<Option<tracks::TrackSet>, SceneError> {
    tracks::TrackSet::parse_within(text, source_name).map_err(|e| match e {
        tracks::TrackError::Syntax {
            source_name,
            line,
            message,
        } => SceneError::Syntax {
            source_name,
            line,
            message,
        },
        tracks::TrackError::Invalid {
            source_name,
            line,
            track,
            field,
            message,
        } => SceneError::Invalid {
            source_name,
            line,
            item: format!("track `{track}`"),
            field: field.to_string(),
            message,
        },
        other => SceneError::Invalid {
            source_name: source_name.to_string(),
            line: 0,
            item: "tracks".into(),
            field: "track".into(),
            message: other.to_string(),
        },
    })
}

fn syntax(text: &str, source_name: &str, e: &toml::de::Error) -> SceneError {
    SceneError::Syntax {
        source_name: source_name.to_string(),
        line: e.span().map(|r| line_of(text, r.start)).unwrap_or(0),
        message: e.message().to_string(),
    }
}

fn parse_desc(
    text: &str,
    source_name: &str,
    load: AssetLoader<'_>,
) -> Result<(SceneDesc, Vec<usize>), SceneError> {
    let file: FileToml = toml::from_str(text).map_err(|e| syntax(text, source_name, &e))?;
    let src = Source {
        text,
        newlines: text
            .bytes()
            .enumerate()
            .filter(|(_, b)| *b == b'\n')
            .map(|(i, _)| i)
            .collect(),
        name: source_name,
        load,
    };
    let mut desc = SceneDesc::default();
    if let Some(s) = file.sky {
        desc.sky = src.sky(&s)?;
    }
    if let Some(s) = &file.sun {
        desc.sun = Some(src.sun(s)?);
    }
    for (i, l) in file.light.iter().enumerate() {
        desc.lights.push(src.light(i, l)?);
    }
    let mut by_name: HashMap<String, usize> = HashMap::new();
    for m in &file.material {
        let line = src.line(m);
        let m = m.get_ref();
        let item = format!("material {:?}", m.name);
        if by_name.contains_key(&m.name) {
            return Err(src.invalid(line, item, "name", "another material has this name".into()));
        }
        let material = src.material(line, &item, m)?;
        by_name.insert(m.name.clone(), desc.materials.len());
        desc.materials.push(material);
    }
    let mut lines = Vec::with_capacity(file.object.len());
    for (i, o) in file.object.iter().enumerate() {
        let line = src.line(o);
        let o = o.get_ref();
        let item = format!("object {i} ({})", o.kind);
        let material = match &o.material {
            Some(name) => *by_name.get(name).ok_or_else(|| {
                src.invalid(
                    line,
                    item.clone(),
                    "material",
                    format!("no material named {name:?}"),
                )
            })?,
            None => *by_name.entry("<default>".into()).or_insert_with(|| {
                desc.materials.push(Material {
                    name: "<default>".into(),
                    color: DVec3::splat(0.6),
                    texture: Texture::Solid,
                });
                desc.materials.len() - 1
            }),
        };
        let shape = src.shape(line, &item, o)?;
        desc.objects.push(Object { shape, material });
        lines.push(line);
    }
    Ok((desc, lines))
}

/// The text being parsed, its name for errors, and how it reads external files.
struct Source<'a> {
    text: &'a str,
    /// Byte offsets of the text's newlines, so that a line is found in log time (a scene of
    /// 10⁴ objects asks for 10⁴ of them).
    newlines: Vec<usize>,
    name: &'a str,
    load: AssetLoader<'a>,
}

impl Source<'_> {
    /// Line of the start of a table.
    fn line<T>(&self, table: &Spanned<T>) -> usize {
        // As `line_of`: the newlines before the offset, plus one.
        let offset = table.span().start.min(self.text.len());
        self.newlines.partition_point(|&i| i < offset) + 1
    }

    fn invalid(&self, line: usize, item: String, field: &str, message: String) -> SceneError {
        SceneError::Invalid {
            source_name: self.name.to_string(),
            line,
            item,
            field: field.to_string(),
            message,
        }
    }

    fn asset(&self, line: usize, item: &str, path: &str, message: String) -> SceneError {
        SceneError::Asset {
            source_name: self.name.to_string(),
            line,
            item: item.to_string(),
            path: path.to_string(),
            message,
        }
    }

    /// `[sky]`: defaults for what is missing.
    fn sky(&self, s: &SkyToml) -> Result<Sky, SceneError> {
        let d = Sky::default();
        let sky = Sky {
            zenith: s.zenith.map_or(d.zenith, v3),
            horizon: s.horizon.map_or(d.horizon, v3),
            ground: s.ground.map_or(d.ground, v3),
            ambient: s.ambient.unwrap_or(d.ambient),
        };
        if !(sky.ambient.is_finite() && sky.ambient >= 0.0) {
            return Err(self.invalid(0, "sky".into(), "ambient", "must be >= 0".into()));
        }
        Ok(sky)
    }

    /// `[sun]`.
    fn sun(&self, s: &Spanned<SunToml>) -> Result<Sun, SceneError> {
        let line = self.line(s);
        let s = s.get_ref();
        let direction = v3(s.direction);
        if !(direction.is_finite() && direction.length() > 0.0) {
            return Err(self.invalid(
                line,
                "sun".into(),
                "direction",
                format!("must be finite and non-zero, found {direction}"),
            ));
        }
        let color = s.color.map_or(DVec3::ONE, v3);
        if !(color.is_finite() && color.min_element() >= 0.0) {
            return Err(self.invalid(
                line,
                "sun".into(),
                "color",
                format!("must be finite and >= 0, found {color}"),
            ));
        }
        Ok(Sun { direction, color })
    }

    /// The `i`th `[[light]]`.
    fn light(&self, i: usize, l: &Spanned<LightToml>) -> Result<PointLight, SceneError> {
        let line = self.line(l);
        let (position, color) = (v3(l.get_ref().position), v3(l.get_ref().color));
        if !position.is_finite() {
            return Err(self.invalid(
                line,
                format!("light {i}"),
                "position",
                format!("must be finite, found {position}"),
            ));
        }
        if !(color.is_finite() && color.min_element() >= 0.0) {
            return Err(self.invalid(
                line,
                format!("light {i}"),
                "color",
                format!("must be finite and >= 0, found {color}"),
            ));
        }
        Ok(PointLight { position, color })
    }

    /// A `[[material]]` table (named `item` in errors), validated.
    fn material(&self, line: usize, item: &str, m: &MaterialToml) -> Result<Material, SceneError> {
        let texture = self.texture(line, item, m)?;
        let material = Material {
            name: m.name.clone(),
            color: v3(m.color),
            texture,
        };
        material
            .validate()
            .map_err(|(field, message)| self.invalid(line, item.to_string(), field, message))?;
        Ok(material)
    }

    /// A material's texture and the fields it requires.
    fn texture(&self, line: usize, item: &str, m: &MaterialToml) -> Result<Texture, SceneError> {
        let need3 = |f: &str, v: Option<[f64; 3]>| {
            v.map(v3).ok_or_else(|| {
                self.invalid(line, item.to_string(), f, "required by this texture".into())
            })
        };
        let need = |f: &str, v: Option<f64>| {
            v.ok_or_else(|| {
                self.invalid(line, item.to_string(), f, "required by this texture".into())
            })
        };
        Ok(match m.texture.as_deref().unwrap_or("solid") {
            "solid" => Texture::Solid,
            "checker" => Texture::Checker {
                color2: need3("color2", m.color2)?,
                size: need("size", m.size)?,
            },
            "noise" => Texture::Noise {
                color2: need3("color2", m.color2)?,
                size: need("size", m.size)?,
            },
            "bricks" => {
                let b = m.brick.unwrap_or([0.4, 0.2]);
                Texture::Bricks {
                    mortar: need3("mortar", m.mortar)?,
                    width: b[0],
                    height: b[1],
                    joint: m.joint.unwrap_or(0.02),
                }
            }
            "windows" => Texture::Windows {
                glass: need3("glass", m.glass)?,
                spacing: m.window_spacing.unwrap_or([3.0, 3.0]),
                size: m.window_size.unwrap_or([1.2, 1.6]),
            },
            "image" => {
                let path = m.image.as_deref().ok_or_else(|| {
                    self.invalid(line, item.to_string(), "image", "required".into())
                })?;
                let asset = |message: String| self.asset(line, item, path, message);
                let bytes = (self.load)(path).map_err(asset)?;
                let img = decode_texture(&bytes).map_err(asset)?;
                if img.width() == 0 || img.height() == 0 {
                    return Err(asset("image is empty".into()));
                }
                Texture::Image {
                    image: Arc::new(TextureImage {
                        width: img.width(),
                        height: img.height(),
                        texels: img.pixels().map(|p| p.0.map(srgb8_to_linear)).collect(),
                    }),
                    size: need("size", m.size)?,
                }
            }
            other => {
                return Err(self.invalid(
                    line,
                    item.to_string(),
                    "texture",
                    format!(
                        "unknown texture `{other}` (expected solid, checker, noise, bricks, windows or image)"
                    ),
                ))
            }
        })
    }

    /// An `[[object]]`'s shape: only the fields of its type, those it needs present, validated.
    fn shape(&self, line: usize, item: &str, o: &ObjectToml) -> Result<Shape, SceneError> {
        let invalid =
            |field: &str, message: String| self.invalid(line, item.to_string(), field, message);
        let allowed: &[&str] = match o.kind.as_str() {
            "sphere" => &["center", "radius"],
            "box" => &["min", "max"],
            "plane" => &["point", "normal"],
            "cylinder" => &["base", "top", "radius"],
            "cone" => &["base", "top", "radius", "radius_top"],
            "triangle" => &["a", "b", "c"],
            "mesh" => &["positions", "triangles", "obj", "translate", "scale"],
            other => {
                return Err(invalid(
                    "type",
                    format!(
                        "unknown primitive `{other}` (expected sphere, box, plane, cylinder, cone, triangle or mesh)"
                    ),
                ))
            }
        };
        if let Some(f) = o.set_fields().into_iter().find(|f| !allowed.contains(f)) {
            return Err(invalid(f, format!("not used by a {}", o.kind)));
        }
        let req3 =
            |f: &str, v: Option<[f64; 3]>| v.map(v3).ok_or_else(|| invalid(f, "missing".into()));
        let req = |f: &str, v: Option<f64>| v.ok_or_else(|| invalid(f, "missing".into()));
        let shape = match o.kind.as_str() {
            "sphere" => Shape::Sphere {
                center: req3("center", o.center)?,
                radius: req("radius", o.radius)?,
            },
            "box" => Shape::Box {
                min: req3("min", o.min)?,
                max: req3("max", o.max)?,
            },
            "plane" => Shape::Plane {
                point: req3("point", o.point)?,
                normal: req3("normal", o.normal)?,
            },
            "cylinder" => {
                let r = req("radius", o.radius)?;
                Shape::Cone {
                    base: req3("base", o.base)?,
                    top: req3("top", o.top)?,
                    radius_base: r,
                    radius_top: r,
                }
            }
            "cone" => Shape::Cone {
                base: req3("base", o.base)?,
                top: req3("top", o.top)?,
                radius_base: req("radius", o.radius)?,
                radius_top: o.radius_top.unwrap_or(0.0),
            },
            "triangle" => Shape::Triangle {
                a: req3("a", o.a)?,
                b: req3("b", o.b)?,
                c: req3("c", o.c)?,
            },
            _ => Shape::Mesh(Arc::new(self.mesh(line, item, o)?)),
        };
        // Validate here too, so the error carries the line.
        shape
            .validate()
            .map_err(|(field, message)| invalid(field, message))?;
        Ok(shape)
    }

    /// A `mesh` object: inline `positions` and `triangles`, or an `obj` file, then scaled and
    /// translated.
    fn mesh(&self, line: usize, item: &str, o: &ObjectToml) -> Result<Mesh, SceneError> {
        let invalid =
            |field: &str, message: String| self.invalid(line, item.to_string(), field, message);
        let mut mesh = match (&o.positions, &o.triangles, &o.obj) {
            (Some(p), Some(t), None) => Mesh {
                positions: p.iter().map(|a| v3(*a)).collect(),
                triangles: t.clone(),
            },
            (None, None, Some(path)) => {
                let asset = |message: String| self.asset(line, item, path, message);
                let bytes = (self.load)(path).map_err(asset)?;
                parse_obj(&bytes).map_err(asset)?
            }
            _ => {
                return Err(invalid(
                    "positions",
                    "a mesh needs either `positions` and `triangles`, or `obj`".into(),
                ))
            }
        };
        let scale = o.scale.unwrap_or(1.0);
        if !(scale.is_finite() && scale > 0.0) {
            return Err(invalid("scale", format!("must be positive, found {scale}")));
        }
        let t = o.translate.map_or(DVec3::ZERO, v3);
        mesh.positions.iter_mut().for_each(|p| *p = *p * scale + t);
        Ok(mesh)
    }
}

/// Triangles of every model in an OBJ file (materials ignored).
fn parse_obj(bytes: &[u8]) -> Result<Mesh, String> {
    let mut reader = std::io::BufReader::new(bytes);
    let opts = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ..Default::default()
    };
    let (models, _) =
        tobj::load_obj_buf(&mut reader, &opts, |_| Ok((Vec::new(), Default::default())))
            .map_err(|e| format!("not a readable OBJ file: {e}"))?;
    let mut mesh = Mesh {
        positions: Vec::new(),
        triangles: Vec::new(),
    };
    for m in models {
        let base = mesh.positions.len() as u32;
        let p = &m.mesh.positions;
        mesh.positions.extend(
            p.chunks_exact(3)
                .map(|c| DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64)),
        );
        mesh.triangles.extend(
            m.mesh
                .indices
                .chunks_exact(3)
                .map(|t| [t[0] + base, t[1] + base, t[2] + base]),
        );
    }
    if mesh.triangles.is_empty() {
        return Err("OBJ file has no faces".into());
    }
    Ok(mesh)
}

fn f(x: f64) -> String {
    // `{:?}` prints the shortest text that reads back to the same f64.
    format!("{x:?}")
}

fn a3(v: DVec3) -> String {
    format!("[{}, {}, {}]", f(v.x), f(v.y), f(v.z))
}

/// Write a scene description in the TOML format (reads back to the same description).
/// Image textures cannot be written (they name files); they are an error.
pub fn to_toml(desc: &SceneDesc) -> Result<String, String> {
    let mut s = String::new();
    let sky = &desc.sky;
    let _ = writeln!(
        s,
        "[sky]\nzenith = {}\nhorizon = {}\nground = {}\nambient = {}\n",
        a3(sky.zenith),
        a3(sky.horizon),
        a3(sky.ground),
        f(sky.ambient)
    );
    if let Some(sun) = &desc.sun {
        let _ = writeln!(
            s,
            "[sun]\ndirection = {}\ncolor = {}\n",
            a3(sun.direction),
            a3(sun.color)
        );
    }
    for l in &desc.lights {
        let _ = writeln!(
            s,
            "[[light]]\nposition = {}\ncolor = {}\n",
            a3(l.position),
            a3(l.color)
        );
    }
    for m in &desc.materials {
        let _ = writeln!(
            s,
            "[[material]]\nname = {:?}\ncolor = {}",
            m.name,
            a3(m.color)
        );
        match &m.texture {
            Texture::Solid => {}
            Texture::Checker { color2, size } | Texture::Noise { color2, size } => {
                let kind = if matches!(m.texture, Texture::Checker { .. }) {
                    "checker"
                } else {
                    "noise"
                };
                let _ = writeln!(
                    s,
                    "texture = \"{kind}\"\ncolor2 = {}\nsize = {}",
                    a3(*color2),
                    f(*size)
                );
            }
            Texture::Bricks {
                mortar,
                width,
                height,
                joint,
            } => {
                let _ = writeln!(
                    s,
                    "texture = \"bricks\"\nmortar = {}\nbrick = [{}, {}]\njoint = {}",
                    a3(*mortar),
                    f(*width),
                    f(*height),
                    f(*joint)
                );
            }
            Texture::Windows {
                glass,
                spacing,
                size,
            } => {
                let _ = writeln!(
                    s,
                    "texture = \"windows\"\nglass = {}\nwindow_spacing = [{}, {}]\nwindow_size = [{}, {}]",
                    a3(*glass),
                    f(spacing[0]),
                    f(spacing[1]),
                    f(size[0]),
                    f(size[1])
                );
            }
            Texture::Image { .. } => {
                return Err(format!(
                    "material {:?}: image textures name files and cannot be emitted",
                    m.name
                ))
            }
        }
        s.push('\n');
    }
    for o in &desc.objects {
        let mat = desc
            .materials
            .get(o.material)
            .ok_or_else(|| format!("object material index {} out of range", o.material))?;
        let _ = writeln!(
            s,
            "[[object]]\ntype = \"{}\"\nmaterial = {:?}",
            o.shape.kind(),
            mat.name
        );
        let _ = match &o.shape {
            Shape::Sphere { center, radius } => {
                writeln!(s, "center = {}\nradius = {}", a3(*center), f(*radius))
            }
            Shape::Box { min, max } => writeln!(s, "min = {}\nmax = {}", a3(*min), a3(*max)),
            Shape::Plane { point, normal } => {
                writeln!(s, "point = {}\nnormal = {}", a3(*point), a3(*normal))
            }
            Shape::Cone {
                base,
                top,
                radius_base,
                radius_top,
            } => {
                let _ = writeln!(
                    s,
                    "base = {}\ntop = {}\nradius = {}",
                    a3(*base),
                    a3(*top),
                    f(*radius_base)
                );
                if radius_base != radius_top {
                    let _ = writeln!(s, "radius_top = {}", f(*radius_top));
                }
                Ok(())
            }
            Shape::Triangle { a, b, c } => {
                writeln!(s, "a = {}\nb = {}\nc = {}", a3(*a), a3(*b), a3(*c))
            }
            Shape::Mesh(m) => {
                let p: Vec<String> = m.positions.iter().map(|p| a3(*p)).collect();
                let t: Vec<String> = m
                    .triangles
                    .iter()
                    .map(|t| format!("[{}, {}, {}]", t[0], t[1], t[2]))
                    .collect();
                writeln!(
                    s,
                    "positions = [{}]\ntriangles = [{}]",
                    p.join(", "),
                    t.join(", ")
                )
            }
        };
        s.push('\n');
    }
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    const SMALL: &str = r#"
[sun]
direction = [0.3, 1, 0.2]

[[material]]
name = "red"
color = [0.8, 0.1, 0.1]
texture = "checker"
color2 = [0.1, 0.1, 0.1]
size = 0.5

[[object]]
type = "sphere"
center = [0, 1, -5]
radius = 1
material = "red"

[[object]]
type = "plane"
point = [0, 0, 0]
normal = [0, 1, 0]
"#;

    #[test]
    fn parses_and_round_trips() {
        let s = Scene::parse_toml(SMALL, "small.toml").unwrap();
        assert_eq!(s.desc().objects.len(), 2);
        assert_eq!(s.desc().materials.len(), 2); // red + the default
        let again = Scene::parse_toml(&to_toml(s.desc()).unwrap(), "again.toml").unwrap();
        assert_eq!(again.desc(), s.desc());
    }

    fn err(text: &str) -> SceneError {
        Scene::parse_toml(text, "bad.toml").unwrap_err()
    }

    #[test]
    fn unknown_primitive_names_line_and_field() {
        let e = err("[[material]]\nname='m'\ncolor=[1,1,1]\n\n[[object]]\ntype = \"pyramid\"\nmaterial='m'\n");
        let msg = e.to_string();
        assert!(msg.starts_with("bad.toml:5:"), "{msg}");
        assert!(msg.contains("pyramid") && msg.contains("`type`"), "{msg}");
    }

    #[test]
    fn negative_and_nan_sizes_are_rejected() {
        let e = err("[[object]]\ntype='sphere'\ncenter=[0,0,0]\nradius=-2\n");
        assert!(
            matches!(&e, SceneError::Invalid { field, line: 1, .. } if field == "radius"),
            "{e}"
        );
        let e = err("\n[[object]]\ntype='sphere'\ncenter=[0,0,0]\nradius=nan\n");
        assert!(
            matches!(&e, SceneError::Invalid { field, line: 2, .. } if field == "radius"),
            "{e}"
        );
        let e = err("[[object]]\ntype='box'\nmin=[0,0,0]\nmax=[1,-1,1]\n");
        assert!(e.to_string().contains("positive"), "{e}");
    }

    #[test]
    fn bad_materials_and_lights_name_line_and_field() {
        let e = err(
            "\n[[material]]\nname='m'\ncolor=[1,1,1]\ntexture='checker'\ncolor2=[0,0,0]\nsize=-1\n",
        );
        assert!(
            matches!(&e, SceneError::Invalid { field, line: 2, .. } if field == "size"),
            "{e}"
        );
        let e = err("[[material]]\nname='m'\ncolor=[1,-1,1]\n");
        assert!(
            matches!(&e, SceneError::Invalid { field, line: 1, .. } if field == "color"),
            "{e}"
        );
        let e = err("[sun]\ndirection=[0,0,0]\n");
        assert!(
            matches!(&e, SceneError::Invalid { field, line: 1, .. } if field == "direction"),
            "{e}"
        );
        let e = err("[[light]]\nposition=[0,nan,0]\ncolor=[1,1,1]\n");
        assert!(
            matches!(&e, SceneError::Invalid { field, .. } if field == "position"),
            "{e}"
        );
        let e = err("[[material]]\nname='m'\ncolor=[1,1,1]\ntexture='marble'\n");
        assert!(e.to_string().contains("marble"), "{e}");
    }

    #[test]
    fn malformed_toml_reports_the_line() {
        let e = err("[[object]]\ntype='sphere'\ncenter=[0,0,0\nradius=1\n");
        match e {
            SceneError::Syntax {
                line, source_name, ..
            } => {
                assert_eq!(source_name, "bad.toml");
                assert!((3..=4).contains(&line), "{line}");
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn misplaced_and_missing_fields_are_named() {
        let e = err("[[object]]\ntype='box'\nmin=[0,0,0]\nmax=[1,1,1]\nradius=3\n");
        assert!(
            matches!(&e, SceneError::Invalid { field, .. } if field == "radius"),
            "{e}"
        );
        let e = err("[[object]]\ntype='box'\nmin=[0,0,0]\n");
        assert!(
            matches!(&e, SceneError::Invalid { field, .. } if field == "max"),
            "{e}"
        );
        let e = err("[[object]]\ntype='box'\nmin=[0,0,0]\nmax=[1,1,1]\nmaterial='nope'\n");
        assert!(e.to_string().contains("nope"), "{e}");
        let e = err("[[object]]\ntype='box'\nmin=[0,0,0]\nmax=[1,1,1]\ncolour=3\n");
        assert!(e.to_string().contains("colour"), "{e}");
    }

    /// Regression: a bad track in a scene file was reported at line 0 of a re-serialised
    /// copy; it names the line of its `[[track]]` in the scene file.
    #[test]
    fn track_errors_in_a_scene_file_name_their_line() {
        let text =
            format!("{SMALL}\n[[track]]\nname='main'\npoints=[[0,1,0],[72,1,0]]\nspacing=1e-9\n");
        let line = text.lines().position(|l| l == "[[track]]").unwrap() + 1;
        let err = tracks_from_scene_toml(&text, "s.toml")
            .unwrap_err()
            .to_string();
        assert!(
            err.starts_with(&format!("s.toml:{line}: track `main`: field `spacing`")),
            "{err}"
        );
        assert!(!err.contains(":0:"), "{err}");
    }

    #[test]
    fn external_files_go_through_the_loader() {
        let text = "[[object]]\ntype='mesh'\nobj='tri.obj'\nscale=2\n";
        let e = Scene::parse_toml(text, "m.toml").unwrap_err();
        assert!(matches!(e, SceneError::Asset { .. }), "{e}");
        let obj = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n".to_vec();
        let s = Scene::parse_toml_with(text, "m.toml", &|p: &str| {
            assert_eq!(p, "tri.obj");
            Ok(obj.clone())
        })
        .unwrap();
        assert_eq!(s.primitive_count(), 1);
        let t = s.first_hit(DVec3::new(0.2, 0.2, 5.0), DVec3::NEG_Z, f64::INFINITY);
        assert_eq!(t, Some(5.0));
    }

    #[test]
    fn tracks_are_read_from_the_scene_file() {
        let text = format!("{SMALL}\n[[track]]\nname='main'\npoints=[[0,1,0],[0,1,-3]]\ncount=2\n");
        let s = Scene::parse_toml(&text, "t.toml").unwrap();
        assert_eq!(s.desc().objects.len(), 2);
        let t = tracks_from_scene_toml(&text, "t.toml").unwrap().unwrap();
        assert_eq!(t.names(), vec!["main"]);
        assert!(tracks_from_scene_toml(SMALL, "t.toml").unwrap().is_none());
    }
}
