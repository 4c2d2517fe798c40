//! Radiosity computed once for the track and shared by every render of the import.
//!
//! POV-Ray samples radiosity anew in every render, and with several threads the samples
//! depend on their timing: two renders of one view differ (balcony: a mean of 2.4 levels, up
//! to 36), and neighbouring references disagree on the same wall. So, for a scene with
//! radiosity, the import first renders every viewpoint's colour once with one thread,
//! saving and reloading one sample file (`+RFO +RFI`): the file holds the samples every
//! view needs, the same bytes on every run. Every colour render then loads it (`+RFI`) and
//! runs on one thread, so that the few samples it still adds are the same each time: two
//! imports give the same pixels, and surfaces seen from several references are lit from
//! the same samples.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use tracks::ReferenceViewpoint;

use super::{remove, PovImport, View};
use crate::pov::sdl::PassKind;
use crate::pov::PovError;
use crate::store::{self, PrerenderDir};

/// What a sample file was gathered for (`DIR/radiosity.json`): another track, face size or
/// sampling needs a new one.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct Gathered {
    scene: PathBuf,
    face_size: u32,
    supersample: u32,
    positions: Vec<[f64; 3]>,
}

/// The shared sample file of a prerender directory.
pub fn radiosity_file(dir: &PrerenderDir) -> PathBuf {
    dir.root().join("radiosity.rad")
}

fn marker(dir: &PrerenderDir) -> PathBuf {
    dir.root().join("radiosity.json")
}

impl PovImport {
    /// Options that make a colour render load the shared samples (and run on one thread);
    /// none without a sample file.
    pub(super) fn radiosity_args(&self) -> Vec<String> {
        match &self.radiosity {
            Some(f) => vec!["+RFI".into(), format!("+RF{}", f.display()), "+WT1".into()],
            None => Vec::new(),
        }
    }

    /// Colour renders load this sample file (`None`: each samples its own).
    pub fn use_radiosity(&mut self, file: Option<PathBuf>) {
        self.radiosity = file;
    }

    /// The sample file in use, if any.
    pub fn radiosity(&self) -> Option<&Path> {
        self.radiosity.as_deref()
    }

    /// For a scene with radiosity: the shared sample file of `dir` for these viewpoints,
    /// gathered unless `dir` holds one made for the same scene, face size, sampling and
    /// positions; then used by every colour render. Nothing for a scene without radiosity.
    /// Returns whether it gathered.
    pub fn prepare_radiosity(
        &mut self,
        dir: &PrerenderDir,
        viewpoints: &[ReferenceViewpoint],
    ) -> Result<bool, PovError> {
        if !self.info.radiosity {
            self.radiosity = None;
            return Ok(false);
        }
        let want = Gathered {
            scene: self.scene.clone(),
            face_size: self.opts.face_size,
            supersample: self.opts.supersample.max(1),
            positions: viewpoints.iter().map(|v| v.position.to_array()).collect(),
        };
        let file = radiosity_file(dir);
        let have: Option<Gathered> = store::read_json(&marker(dir)).ok();
        if file.is_file() && have.as_ref() == Some(&want) {
            self.radiosity = Some(file);
            return Ok(false);
        }
        self.radiosity = None;
        let tmp = self.opts.work_dir.join("radiosity-gather.rad");
        remove(&tmp)?;
        let ss = self.opts.supersample.max(1);
        let fine = ss * self.opts.face_size;
        for (i, vp) in viewpoints.iter().enumerate() {
            let view = View {
                pov: self.opts.up.pov_from_railview(vp.position),
                near: 0.0,
                range: 0.0,
            };
            let stem = format!("s{:04}_radiosity", vp.index);
            let mut job = self.job(&stem, PassKind::Color, fine, view, None)?;
            job.name = format!(
                "sample {} radiosity samples ({})",
                vp.index,
                self.scene.display()
            );
            if i > 0 {
                job.extra.push("+RFI".into());
            }
            job.extra.extend([
                "+RFO".into(),
                format!("+RF{}", tmp.display()),
                "+WT1".into(),
            ]);
            let stats = self.povray.run(&job)?;
            self.record(vp.index, "radiosity", fine, &job, stats)?;
            remove(&job.output)?;
        }
        let bytes = std::fs::read(&tmp).map_err(|source| PovError::Io {
            path: tmp.clone(),
            source,
        })?;
        // Every shard gathers the same bytes: written only where they differ.
        store::write_if_changed(&file, &bytes)?;
        store::write_json(&marker(dir), &want)?;
        remove(&tmp)?;
        self.radiosity = Some(file);
        Ok(true)
    }
}
