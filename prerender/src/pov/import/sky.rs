//! The scene's sky alone, behind every occluder: what the background layer shows where a view
//! between samples looks past what both references see.

use glam::DVec3;
use tracks::CubeMap;

use super::{remove, PovImport, View, MAX_SUPERSAMPLE};
use crate::pov::decode;
use crate::pov::frame::MeshLayout;
use crate::pov::sdl::PassKind;
use crate::pov::PovError;

impl PovImport {
    /// The sky in every direction from `position` (railview frame): the colour pass with
    /// every ray starting `beyond` scene units out, past every object the references see
    /// (the slab trick: the mesh camera's origin moved out along each ray), so that only
    /// what lies at infinity is drawn — `sky_sphere`, `background`, and the scene's fog over
    /// an endless ray, as the panoramas show it where they see sky. An object farther than
    /// `beyond` (or an infinite plane below the horizon) shows too; the caller checks the
    /// result against the panoramas' own sky.
    pub fn render_sky(
        &mut self,
        position: DVec3,
        beyond: f64,
    ) -> Result<CubeMap<[u8; 3]>, PovError> {
        if !(beyond.is_finite() && beyond > 0.0) {
            return Err(PovError::Parameter {
                name: "sky",
                message: format!("the sky pass starts rays at a positive distance, not {beyond}"),
            });
        }
        let ss = self.opts.supersample.clamp(1, MAX_SUPERSAMPLE);
        let fine = ss * self.opts.face_size;
        let view = View {
            pov: self.opts.up.pov_from_railview(position),
            near: beyond,
            range: 0.0,
        };
        let mut job = self.job("sky_alone", PassKind::Color, fine, view, None)?;
        job.name = format!("the sky alone ({})", self.scene.display());
        let stats = self.povray.run(&job)?;
        self.record(0, "sky", fine, &job, stats)?;
        let map = decode::read_mesh_png8(&job.output, &MeshLayout::new(fine))?;
        remove(&job.output)?;
        Ok(if ss > 1 {
            decode::downsample(&map, ss)
        } else {
            map
        })
    }
}
