//! Ground truth: what a perspective camera sees in the scene a walkthrough was made from,
//! rendered by the renderer that made its panoramas, anti-aliased.
//!
//! - [`GroundTruth::Traced`]: built-in scenes and TOML scene files, through the built-in
//!   tracer with `supersample²` stratified rays per pixel averaged in linear light (a box
//!   filter over the pixel).
//! - [`GroundTruth::Pov`]: POV-Ray imports, through POV-Ray itself with a perspective camera
//!   at the same pose and the import's settings (scene, up axis, binary, threads, timeout),
//!   rendered at `supersample`× the size and box-filtered the same way.
//!
//! [`GroundTruth::for_prerender`] picks the right one from a prerender directory's report.
//!
//! ```
//! use prerender::truth::GroundTruth;
//! let mut truth = GroundTruth::for_scene("castle", 2).unwrap();
//! let at = prerender::scenes::builtin("castle").unwrap().tracks.get("main").unwrap()
//!     .viewpoints()[0].position;
//! let camera = tracks::PerspectiveCamera {
//!     position: at, yaw_deg: 0.0, pitch_deg: 0.0, fov_deg: 90.0, width: 8, height: 6,
//! };
//! let rgb = truth.render(&camera).unwrap();
//! assert_eq!(rgb.len(), 48);
//! ```

use std::path::{Path, PathBuf};

use tracks::PerspectiveCamera;

use crate::pov::{PovError, PovImport};
use crate::scene::Scene;
use crate::store::{PrerenderDir, PrerenderReport, StoreError};

/// Why no ground truth could be made or rendered.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TruthError {
    #[error(
        "scene `{0}` is neither a built-in scene ({names}) nor a scene file that exists here \
         (a relative path is read from the current directory)",
        names = crate::scenes::names_help()
    )]
    UnknownScene(String),
    #[error("scene file {path}: {message}")]
    SceneFile { path: PathBuf, message: String },
    #[error("renderer `{renderer}` of {report} has no ground truth (only `builtin` and `povray`)")]
    Renderer { renderer: String, report: PathBuf },
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error(transparent)]
    Pov(#[from] PovError),
}

/// The exact renderer of a walkthrough's scene.
pub enum GroundTruth {
    Traced {
        scene: Box<Scene>,
        /// Rays per pixel along each axis.
        supersample: u32,
    },
    Pov {
        import: Box<PovImport>,
        supersample: u32,
    },
}

impl GroundTruth {
    /// The built-in tracer on a built-in scene (`castle`, `builtin:castle`) or a TOML scene
    /// file (read with its external files relative to it).
    pub fn for_scene(spec: &str, supersample: u32) -> Result<GroundTruth, TruthError> {
        Ok(GroundTruth::Traced {
            scene: Box::new(load_scene(spec)?),
            supersample: supersample.clamp(1, 16),
        })
    }

    /// The ground truth of the scene a prerender directory was rendered from: the tracer for
    /// `builtin` renders, POV-Ray re-created from the import's record for `povray` ones (its
    /// generated files go to `work_dir`).
    pub fn for_prerender(
        dir: &PrerenderDir,
        supersample: u32,
        work_dir: &Path,
    ) -> Result<GroundTruth, TruthError> {
        let pre: PrerenderReport = dir.read_report()?;
        match pre.renderer.as_str() {
            "builtin" => GroundTruth::for_scene(&pre.scene, supersample),
            "povray" => Ok(GroundTruth::Pov {
                import: Box::new(PovImport::from_report(dir, &pre, work_dir)?),
                supersample: supersample.clamp(1, 16),
            }),
            other => Err(TruthError::Renderer {
                renderer: other.to_string(),
                report: dir.report_json(),
            }),
        }
    }

    /// The view of `camera`, sRGB, rows from the top.
    pub fn render(&mut self, camera: &PerspectiveCamera) -> Result<Vec<[u8; 3]>, TruthError> {
        Ok(match self {
            GroundTruth::Traced { scene, supersample } => {
                crate::render::render_perspective(scene, camera, *supersample).color
            }
            GroundTruth::Pov {
                import,
                supersample,
            } => import.render_perspective(camera, *supersample)?,
        })
    }

    /// Rays per pixel along each axis.
    pub fn supersample(&self) -> u32 {
        match self {
            GroundTruth::Traced { supersample, .. } | GroundTruth::Pov { supersample, .. } => {
                *supersample
            }
        }
    }

    /// One line for reports: which renderer and how it anti-aliases.
    pub fn describe(&self) -> String {
        let ss = self.supersample();
        let aa = if ss > 1 {
            format!("{ss}×{ss} rays per pixel averaged in linear light (box filter)")
        } else {
            "one ray per pixel centre (not anti-aliased)".into()
        };
        match self {
            GroundTruth::Traced { .. } => format!("the built-in ray tracer, {aa}"),
            GroundTruth::Pov { import, .. } => format!(
                "POV-Ray ({}) with a perspective camera, {aa}",
                import.povray_version()
            ),
        }
    }
}

/// A built-in scene by name, or a TOML scene file.
pub fn load_scene(spec: &str) -> Result<Scene, TruthError> {
    let name = spec.strip_prefix("builtin:").unwrap_or(spec);
    if let Some(b) = crate::scenes::builtin(name) {
        return Ok(b.scene);
    }
    let path = Path::new(spec);
    if !path.is_file() {
        return Err(TruthError::UnknownScene(spec.to_string()));
    }
    let err = |message: String| TruthError::SceneFile {
        path: path.to_path_buf(),
        message,
    };
    let text = std::fs::read_to_string(path).map_err(|e| err(e.to_string()))?;
    let base = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let loader = move |rel: &str| -> Result<Vec<u8>, String> {
        std::fs::read(base.join(rel)).map_err(|e| format!("{}: {e}", base.join(rel).display()))
    };
    Scene::parse_toml_with(&text, spec, &loader).map_err(|e| err(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_scenes_are_named() {
        let e = GroundTruth::for_scene("no-such-scene.toml", 1)
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("no-such-scene.toml") && e.contains("castle"),
            "{e}"
        );
    }

    #[test]
    fn supersampled_truth_is_the_box_filter_of_finer_rays() {
        let mut truth = GroundTruth::for_scene("castle", 2).unwrap();
        assert!(truth.describe().contains("2×2"));
        let at = crate::scenes::builtin("castle")
            .unwrap()
            .tracks
            .get("main")
            .unwrap()
            .viewpoints()[1]
            .position;
        let cam = PerspectiveCamera {
            position: at,
            yaw_deg: 20.0,
            pitch_deg: 5.0,
            fov_deg: 70.0,
            width: 12,
            height: 8,
        };
        let aa = truth.render(&cam).unwrap();
        // The same rays: the 2× image, averaged over 2×2 blocks in linear light.
        let fine_cam = PerspectiveCamera {
            width: 24,
            height: 16,
            ..cam
        };
        let mut one = GroundTruth::for_scene("castle", 1).unwrap();
        let fine = one.render(&fine_cam).unwrap();
        let flat: Vec<u8> = fine.iter().flatten().copied().collect();
        let boxed = crate::pov::decode::box_filter(&flat, 12, 8, 2);
        let diffs: Vec<i32> = aa
            .iter()
            .zip(&boxed)
            .flat_map(|(a, b)| (0..3).map(move |c| (a[c] as i32 - b[c] as i32).abs()))
            .collect();
        // Both quantise to 8 bits, before (fine) or after (aa) averaging: a step or two. Only
        // where a ray is brighter than white (a lamp, the sun on a pale wall) does the fine
        // image clip each ray before averaging, and the anti-aliased one after.
        let close = diffs.iter().filter(|d| **d <= 2).count();
        assert!(
            close * 100 >= diffs.len() * 95,
            "{close} of {}",
            diffs.len()
        );
    }
}
