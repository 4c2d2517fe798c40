//! Generated POV-Ray SDL: what we learn from a scene's text, and the wrapper files that
//! include the scene unchanged and add our camera (and, for depth passes, the fog trick).
//!
//! Every number that changes per render (camera position, near/far, fog distances) is passed
//! on the command line with `Declare=`; the wrappers only differ by pass kind and mesh file.
//! All our identifiers start with `Rv` so they cannot collide with a scene's own.

use std::path::Path;

use super::frame::{BLOCK_MESH_NAME, LEAD_MESH_NAME, MESH_NAME, NEAR_NAME};

/// What the driver needs to know about a scene, read from its top-level text.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneInfo {
    /// The first `assumed_gamma` value (POV-Ray ignores later ones), 1.0 when absent.
    pub assumed_gamma: f64,
    /// Whether the text mentions `assumed_gamma` at all.
    pub gamma_found: bool,
    /// Whether the scene turns on radiosity (depth passes then override its settings).
    pub radiosity: bool,
}

/// Remove `//` and `/* */` comments and string literals' contents (kept as `""`), so keyword
/// searches see only code.
pub fn strip_comments(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let b = text.as_bytes();
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'/' && b.get(i + 1) == Some(&b'/') {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if b[i] == b'/' && b.get(i + 1) == Some(&b'*') {
            i += 2;
            while i < b.len() && !(b[i] == b'*' && b.get(i + 1) == Some(&b'/')) {
                if b[i] == b'\n' {
                    out.push('\n');
                }
                i += 1;
            }
            i += 2;
        } else if b[i] == b'"' {
            out.push('"');
            i += 1;
            while i < b.len() && b[i] != b'"' && b[i] != b'\n' {
                i += 1;
            }
            out.push('"');
            i += 1;
        } else {
            // Copy one UTF-8 character.
            let ch_len = text[i..].chars().next().map_or(1, char::len_utf8);
            out.push_str(&text[i..i + ch_len]);
            i += ch_len;
        }
    }
    out
}

fn is_ident(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

/// Byte offsets of whole-word occurrences of `word` in `code`.
fn word_positions<'a>(code: &'a str, word: &'a str) -> impl Iterator<Item = usize> + 'a {
    code.match_indices(word).filter_map(move |(i, _)| {
        let before = code[..i].chars().next_back();
        let after = code[i + word.len()..].chars().next();
        (!before.is_some_and(is_ident) && !after.is_some_and(is_ident)).then_some(i)
    })
}

impl SceneInfo {
    /// Inspect a scene's text (not its includes).
    pub fn from_text(text: &str) -> SceneInfo {
        let code = strip_comments(text);
        let gamma = word_positions(&code, "assumed_gamma").next().map(|i| {
            let rest = code[i + "assumed_gamma".len()..].trim_start();
            let num: String = rest
                .chars()
                .take_while(|c| c.is_ascii_digit() || matches!(c, '.' | 'e' | 'E' | '+' | '-'))
                .collect();
            num.parse::<f64>().ok().filter(|g| *g > 0.0)
        });
        let radiosity = word_positions(&code, "radiosity").next().is_some();
        SceneInfo {
            assumed_gamma: gamma.flatten().unwrap_or(1.0),
            gamma_found: gamma.is_some(),
            radiosity,
        }
    }
}

/// The kinds of wrapper the driver renders.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PassKind {
    /// The scene as it is, through the mesh camera.
    Color,
    /// Fog-trick depth: black filter fog plus one coloured fog per channel.
    Depth,
    /// Only the black filter fog: what the scene's own fog adds (subtracted from `Depth`).
    FogOnly,
}

/// Declared names the wrappers read.
pub mod names {
    pub const CAM_X: &str = "RvCamX";
    pub const CAM_Y: &str = "RvCamY";
    pub const CAM_Z: &str = "RvCamZ";
    /// Far distance minus near, or 0 for "no limit".
    pub const RANGE: &str = "RvRange";
    pub const D1: &str = "RvD1";
    pub const D2: &str = "RvD2";
    pub const D3: &str = "RvD3";
    pub const K: &str = "RvK";
    /// A perspective camera's direction, right and up vectors (POV-Ray coordinates).
    pub const DIR: [&str; 3] = ["RvDirX", "RvDirY", "RvDirZ"];
    pub const RIGHT: [&str; 3] = ["RvRightX", "RvRightY", "RvRightZ"];
    pub const UP: [&str; 3] = ["RvUpX", "RvUpY", "RvUpZ"];
}

/// Quote a path as an SDL string literal; `None` if it cannot be written as one.
pub fn sdl_string(path: &Path) -> Option<String> {
    let s = path.to_str()?;
    (!s.contains('"') && !s.contains('\\') && !s.contains('\n')).then(|| format!("\"{s}\""))
}

/// The radiosity settings the depth passes use when the scene has radiosity: the fog trick
/// discards all lighting, so the cheapest radiosity gives the same output about 10× faster.
const CHEAP_RADIOSITY: &str =
    "global_settings { radiosity { pretrace_start 0.08 pretrace_end 0.08 \
     count 2 nearest_count 1 error_bound 10 recursion_limit 1 } }";

/// Wrapper text for a mesh-camera pass. `scene` and `mesh` are SDL string literals.
pub fn mesh_wrapper(kind: PassKind, scene: &str, mesh: &str, info: &SceneInfo) -> String {
    use names::*;
    let mut s = format!(
        "// generated by railview import-pov; the scene is included unchanged\n\
         #include {scene}\n\
         #include {mesh}\n\
         camera {{\n  mesh_camera {{ 1 0 #if ({RANGE} > 0) {RANGE} #end\n    \
         mesh {{ {MESH_NAME} translate <{CAM_X}, {CAM_Y}, {CAM_Z}> }}\n  }}\n  \
         location <0, 0, {NEAR_NAME}>\n}}\n"
    );
    push_pass_settings(&mut s, kind, info);
    s
}

/// Wrapper text for a [`super::frame::BlockLayout`] render: the scene seen from each of
/// `positions` (POV-Ray coordinates) at once, one block of rows each, in order.
pub fn block_wrapper(
    kind: PassKind,
    scene: &str,
    mesh: &str,
    info: &SceneInfo,
    positions: &[glam::DVec3],
) -> String {
    use names::*;
    let at = |p: &glam::DVec3| format!("<{:.12e}, {:.12e}, {:.12e}>", p.x, p.y, p.z);
    let first = positions
        .first()
        .map(at)
        .unwrap_or_else(|| "<0, 0, 0>".into());
    let mut s = format!(
        "// generated by railview import-pov; the scene is included unchanged\n\
         #include {scene}\n\
         #include {mesh}\n\
         camera {{\n  mesh_camera {{ 1 1 #if ({RANGE} > 0) {RANGE} #end\n    \
         mesh {{ {LEAD_MESH_NAME} translate {first} }}\n"
    );
    for p in positions {
        s.push_str(&format!(
            "    mesh {{ {BLOCK_MESH_NAME} translate {} }}\n",
            at(p)
        ));
    }
    s.push_str(&format!("  }}\n  location <0, 0, {NEAR_NAME}>\n}}\n"));
    push_pass_settings(&mut s, kind, info);
    s
}

/// What a pass adds after the camera: the fogs and cheap settings of depth passes.
fn push_pass_settings(s: &mut String, kind: PassKind, info: &SceneInfo) {
    use names::*;
    match kind {
        PassKind::Color => {}
        PassKind::Depth | PassKind::FogOnly => {
            s.push_str("fog { distance 1e9 rgbf <0, 0, 0, 1> }\n");
            if kind == PassKind::Depth {
                s.push_str(&format!(
                    "fog {{ distance {D1} rgb <{K}, 0, 0> }}\n\
                     fog {{ distance {D2} rgb <0, {K}, 0> }}\n\
                     fog {{ distance {D3} rgb <0, 0, {K}> }}\n"
                ));
            }
            s.push_str("global_settings { max_trace_level 1 }\n");
            if info.radiosity {
                s.push_str(CHEAP_RADIOSITY);
                s.push('\n');
            }
        }
    }
}

/// Wrapper text for an equirectangular colour preview with POV-Ray's spherical camera.
pub fn spherical_wrapper(scene: &str, camera_vectors: &str) -> String {
    use names::*;
    format!(
        "// generated by railview import-pov (equirectangular preview)\n\
         #include {scene}\n\
         camera {{ spherical angle 360 180 location <{CAM_X}, {CAM_Y}, {CAM_Z}> {camera_vectors} }}\n"
    )
}

/// Wrapper text for a perspective colour view (ground truth): the camera's vectors come from
/// `Declare=`, so POV-Ray traces `direction + (x − ½)·right + (½ − y)·up` for the pixel centre
/// `(x, y)` in units of the image size, exactly as [`tracks::PerspectiveCamera`] does.
pub fn perspective_wrapper(scene: &str) -> String {
    use names::*;
    let v = |n: [&str; 3]| format!("<{}, {}, {}>", n[0], n[1], n[2]);
    format!(
        "// generated by railview (perspective ground truth); the scene is included unchanged\n\
         #include {scene}\n\
         camera {{ perspective location <{CAM_X}, {CAM_Y}, {CAM_Z}>\n  \
         direction {} right {} up {} }}\n",
        v(DIR),
        v(RIGHT),
        v(UP)
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gamma_and_radiosity_found_in_code_only() {
        let info = SceneInfo::from_text(
            "// assumed_gamma 3.0\n/* radiosity { } */\nglobal_settings {\n  assumed_gamma 2.2\n}\n\
             global_settings { assumed_gamma 1.0 }\n#include \"radiosity.inc\"\n",
        );
        assert_eq!(info.assumed_gamma, 2.2);
        assert!(info.gamma_found);
        assert!(!info.radiosity, "comments and strings are not code");
        let info = SceneInfo::from_text("global_settings { radiosity { count 10 } }");
        assert!(info.radiosity);
        assert!(!info.gamma_found);
        assert_eq!(info.assumed_gamma, 1.0);
        assert!(!SceneInfo::from_text("#declare my_radiosity_on = 1;").radiosity);
    }

    #[test]
    fn strip_keeps_line_count() {
        let t = "a /* x\ny\nz */ b // c\nd \"e//f\" g\n";
        let s = strip_comments(t);
        assert_eq!(s.lines().count(), t.lines().count());
        assert!(s.contains("\"\" g"));
        assert!(!s.contains('x') && !s.contains('f'));
    }

    #[test]
    fn wrappers_only_add_fog_to_depth_passes() {
        let info = SceneInfo {
            assumed_gamma: 1.0,
            gamma_found: true,
            radiosity: true,
        };
        let c = mesh_wrapper(PassKind::Color, "\"/s.pov\"", "\"/m.inc\"", &info);
        assert!(c.starts_with("// generated") && !c.contains("fog"));
        let d = mesh_wrapper(PassKind::Depth, "\"/s.pov\"", "\"/m.inc\"", &info);
        assert_eq!(d.matches("fog {").count(), 4);
        assert!(d.contains("radiosity"));
        let p = mesh_wrapper(PassKind::FogOnly, "\"/s.pov\"", "\"/m.inc\"", &info);
        assert_eq!(p.matches("fog {").count(), 1);
        assert_eq!(
            sdl_string(Path::new("/a b/c.pov")).unwrap(),
            "\"/a b/c.pov\""
        );
        assert!(sdl_string(Path::new("/a\"b")).is_none());
    }
}
