//! Whole views rendered through POV-Ray's own cameras rather than the mesh camera: the
//! equirectangular preview and the perspective ground truth.

use std::fs;
use std::path::Path;

use tracks::{PerspectiveCamera, ReferenceViewpoint};

use super::{remove, PovImport, RenderRecord};
use crate::pov::decode;
use crate::pov::runner::{OutputFormat, RenderJob};
use crate::pov::sdl::{self, names};
use crate::pov::PovError;
use crate::runlog::RunEvent;
use crate::store;

impl PovImport {
    /// Equirectangular colour preview (`width × width/2`) with POV-Ray's spherical camera,
    /// centred on railview −z, written to `out` as PNG.
    pub fn render_preview(
        &mut self,
        vp: &ReferenceViewpoint,
        width: u32,
        out: &Path,
    ) -> Result<(), PovError> {
        let width = width.max(2);
        let wrapper = self
            .opts
            .work_dir
            .join(format!("wrap_spherical_{}.pov", self.opts.up.name()));
        let text = sdl::spherical_wrapper(&self.scene_sdl, self.opts.up.spherical_camera_vectors());
        store::write_atomic(&wrapper, text.as_bytes())?;
        let pov = self.opts.up.pov_from_railview(vp.position);
        let stem = format!("s{:04}_preview", vp.index);
        let output = self.opts.work_dir.join(format!("{stem}.png"));
        let job = RenderJob {
            name: format!("sample {} preview ({})", vp.index, self.scene.display()),
            wrapper,
            output: output.clone(),
            log: self.opts.work_dir.join("logs").join(format!("{stem}.log")),
            width,
            height: width / 2,
            format: OutputFormat::Png8,
            block_size: 32,
            library_dirs: self
                .scene
                .parent()
                .map(Path::to_path_buf)
                .into_iter()
                .collect(),
            declares: vec![
                (names::CAM_X, pov.x),
                (names::CAM_Y, pov.y),
                (names::CAM_Z, pov.z),
            ],
            extra: self.radiosity_args(),
        };
        let stats = self.povray.run(&job)?;
        let record = RenderRecord {
            sample: vp.index,
            pass: "preview".into(),
            face_size: 0,
            pixels: width as u64 * (width / 2) as u64,
            stats,
            depth: None,
        };
        if let Some(p) = self.progress.as_mut() {
            p(&record);
        }
        self.log(RunEvent::Povray(record.clone()))?;
        self.records.push(record);
        let bytes = fs::read(&output).map_err(|source| PovError::Io {
            path: output.clone(),
            source,
        })?;
        store::write_atomic(out, &bytes)?;
        remove(&output)
    }

    /// A perspective colour view through POV-Ray's own perspective camera (the ground truth
    /// of an import): rendered at `supersample`× the camera's size, so each pixel holds
    /// `supersample²` stratified rays at the offsets the built-in tracer uses, then averaged
    /// in linear light (a box filter). Rows from the top, sRGB.
    pub fn render_perspective(
        &mut self,
        camera: &PerspectiveCamera,
        supersample: u32,
    ) -> Result<Vec<[u8; 3]>, PovError> {
        let ss = supersample.clamp(1, 16);
        let (w, h) = (camera.width.max(1), camera.height.max(1));
        if !(camera.fov_deg > 0.0 && camera.fov_deg < 180.0) {
            return Err(PovError::Parameter {
                name: "fov",
                message: format!("must be in (0, 180) degrees, found {}", camera.fov_deg),
            });
        }
        let wrapper = self
            .opts
            .work_dir
            .join(format!("wrap_perspective_{}.pov", self.opts.up.name()));
        store::write_atomic(
            &wrapper,
            sdl::perspective_wrapper(&self.scene_sdl).as_bytes(),
        )?;
        // ray(x, y) = f + (2x/w − 1)·t·r + (1 − 2y/h)·t·(h/w)·u, x and y in pixels.
        let (r, u, f) = camera.basis();
        let t = (camera.fov_deg.to_radians() * 0.5).tan();
        let up = self.opts.up;
        let dir = up.pov_from_railview(f);
        let right = up.pov_from_railview(r * (2.0 * t));
        let upv = up.pov_from_railview(u * (2.0 * t * h as f64 / w as f64));
        let pos = up.pov_from_railview(camera.position);
        let mut declares = vec![
            (names::CAM_X, pos.x),
            (names::CAM_Y, pos.y),
            (names::CAM_Z, pos.z),
        ];
        for (n, v) in [(names::DIR, dir), (names::RIGHT, right), (names::UP, upv)] {
            declares.extend([(n[0], v.x), (n[1], v.y), (n[2], v.z)]);
        }
        self.truth_renders += 1;
        let stem = format!("truth_{:05}", self.truth_renders);
        let output = self.opts.work_dir.join(format!("{stem}.png"));
        let job = RenderJob {
            name: format!("ground truth view ({})", self.scene.display()),
            wrapper,
            output: output.clone(),
            log: self.opts.work_dir.join("logs").join(format!("{stem}.log")),
            width: w * ss,
            height: h * ss,
            format: OutputFormat::Png8,
            block_size: 32,
            library_dirs: self
                .scene
                .parent()
                .map(Path::to_path_buf)
                .into_iter()
                .collect(),
            declares,
            extra: self.radiosity_args(),
        };
        let stats = self.povray.run(&job)?;
        let record = RenderRecord {
            sample: 0,
            pass: "truth".into(),
            face_size: 0,
            pixels: (w * ss) as u64 * (h * ss) as u64,
            stats,
            depth: None,
        };
        if let Some(p) = self.progress.as_mut() {
            p(&record);
        }
        self.records.push(record);
        let fine = image::open(&output)
            .map_err(|e| PovError::Output {
                path: output.clone(),
                message: e.to_string(),
            })?
            .to_rgb8();
        remove(&output)?;
        if fine.dimensions() != (w * ss, h * ss) {
            return Err(PovError::Output {
                path: output,
                message: format!(
                    "{}×{} pixels, expected {}×{}",
                    fine.width(),
                    fine.height(),
                    w * ss,
                    h * ss
                ),
            });
        }
        Ok(decode::box_filter(fine.as_raw(), w, h, ss))
    }
}
