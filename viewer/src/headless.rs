//! Headless use of the renderer: open a walkthrough by name (`synth:street`, a database or a
//! prerender directory) and place cameras along its track. Evaluation against the ground
//! truth is in [`crate::eval`].

use std::path::Path;

use glam::DVec3;
use tracks::{SlabRange, TrackSet};

use crate::gpu::GpuError;
use crate::plan::PlanError;
use crate::refview::LayerMeshing;
use crate::source::{self, LoadOptions, SourceError, Walkthrough};
use crate::synth::{views_along, Scene};

/// Errors of the headless commands.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum HeadlessError {
    #[error(transparent)]
    Source(#[from] SourceError),
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error(transparent)]
    Plan(#[from] PlanError),
    #[error("{0}")]
    Parameter(String),
}

/// The synthetic street walkthrough: samples 1.5 m apart over 4.5 m along x at eye height.
pub fn synth_street(
    face_size: u32,
    slabs: &[SlabRange],
    params: LayerMeshing,
) -> Result<Walkthrough, HeadlessError> {
    synth_street_spaced(face_size, slabs, params, 1.5)
}

/// Other databases of the synthetic street at faces of 64 px, named by how they differ
/// from the default: one slab, a coarser mesh, wider spacing (what `railview eval
/// synth:street` weighs against each other).
pub fn synth_street_variants() -> Result<Vec<(&'static str, Walkthrough)>, HeadlessError> {
    let one = [SlabRange {
        near: 0.0,
        far: f64::INFINITY,
    }];
    let base = LayerMeshing::default();
    let step4 = LayerMeshing { step: 4, ..base };
    let slabs3 = Scene::street_slabs();
    Ok(vec![
        ("db slabs=1", synth_street_spaced(64, &one, base, 1.5)?),
        ("db step=4", synth_street_spaced(64, &slabs3, step4, 1.5)?),
        (
            "db spacing=2.25",
            synth_street_spaced(64, &slabs3, base, 2.25)?,
        ),
    ])
}

/// The synthetic street with samples `spacing_m` apart.
pub fn synth_street_spaced(
    face_size: u32,
    slabs: &[SlabRange],
    params: LayerMeshing,
    spacing_m: f64,
) -> Result<Walkthrough, HeadlessError> {
    let set = TrackSet::parse(
        &format!(
            "[[track]]\nname = \"main\"\npoints = [[0, 1.7, 0], [4.5, 1.7, 0]]\nspacing = {spacing_m}\n"
        ),
        "synth:street",
    )
    .map_err(|e| HeadlessError::Parameter(e.to_string()))?;
    let track = set.tracks[0].clone();
    let samples: Vec<(f64, DVec3)> = track
        .viewpoints()
        .iter()
        .map(|v| (v.s, v.position))
        .collect();
    let views = views_along(&Scene::street(), &samples, face_size, 16, slabs, params)
        .map_err(SourceError::from)?;
    let bytes = views
        .iter()
        .map(|v| {
            let tex: usize = v
                .layers
                .iter()
                .map(|l| l.levels[0].as_slice().len() * 4)
                .sum();
            let mesh: usize = v
                .tiles
                .iter()
                .map(|t| t.mesh.vertices.len() * 12 + t.mesh.indices.len() * 4)
                .sum();
            (tex + mesh) as u64
        })
        .sum();
    Ok(Walkthrough::single(
        "synth:street".into(),
        track,
        views,
        slabs.to_vec(),
        bytes,
    ))
}

/// Open `spec`: `synth:street` or a directory (database or prerender output).
pub fn open(
    spec: &str,
    track: Option<&str>,
    opts: LoadOptions,
) -> Result<Walkthrough, HeadlessError> {
    if spec == "synth:street" {
        return synth_street(64, &Scene::street_slabs(), opts.mesh);
    }
    Ok(source::open(Path::new(spec), track, opts)?)
}

/// Parse `WxH`.
pub fn parse_size(text: &str) -> Result<(u32, u32), String> {
    let (w, h) = text
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("size `{text}`: expected WxH, e.g. 1280x720"))?;
    let p = |s: &str| {
        s.trim()
            .parse::<u32>()
            .ok()
            .filter(|v| (1..=16384).contains(v))
            .ok_or_else(|| format!("size `{text}`: `{s}` is not a number in 1..=16384"))
    };
    Ok((p(w)?, p(h)?))
}

/// Yaw (degrees, camera convention) that looks along the track at `s`.
pub fn yaw_along(walk: &Walkthrough, s: f64) -> f64 {
    let t = walk.track.tangent_at(s);
    if t.x == 0.0 && t.z == 0.0 {
        0.0
    } else {
        t.x.atan2(-t.z).to_degrees()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_and_reject_nonsense() {
        assert_eq!(parse_size("1280x720"), Ok((1280, 720)));
        assert_eq!(parse_size("1X1"), Ok((1, 1)));
        for bad in ["", "12", "0x5", "ax3", "5x-1", "99999x2"] {
            assert!(parse_size(bad).is_err(), "{bad}");
        }
    }
}
