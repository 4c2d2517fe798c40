//! The network of tracks a prerender directory was rendered along: every track of its
//! `track.toml` when the report names [`ALL_TRACKS`], else the one it names. Every stage
//! after `prerender` walks the same graph: its viewpoints in the report's order, its
//! segments for culling, its junctions for the manifest.

use prerender::store::{PrerenderDir, PrerenderReport};
use tracks::network::Network;
use tracks::TrackSet;

use crate::error::{input, Context, Result};

/// The track name that means every track of a scene or track file.
pub const ALL_TRACKS: &str = "all";

/// The network of `pre`'s tracks, read from `dir`'s `track.toml`. Where that file is missing
/// or no longer gives the report's viewpoints (a directory from an older version), straight
/// segments through the viewpoints in order stand in for it.
pub fn network_of(dir: &PrerenderDir, pre: &PrerenderReport) -> Result<Network> {
    let from_file = || -> Option<Network> {
        let text = std::fs::read_to_string(dir.track_toml()).ok()?;
        let set = TrackSet::parse(&text, &dir.track_toml().display().to_string()).ok()?;
        let tracks = if pre.track == ALL_TRACKS {
            set.tracks
        } else {
            vec![set.get(&pre.track).or_else(|| set.tracks.first())?.clone()]
        };
        let net = Network::new(tracks).ok()?;
        let same = net.viewpoints.len() == pre.viewpoints.len()
            && net
                .viewpoints
                .iter()
                .zip(&pre.viewpoints)
                .all(|(a, b)| a.distance(b.position) <= 1e-6 * (1.0 + a.length()));
        same.then_some(net)
    };
    if let Some(net) = from_file() {
        return Ok(net);
    }
    let positions: Vec<glam::DVec3> = pre.viewpoints.iter().map(|v| v.position).collect();
    match positions.len() {
        0 => Err(input!("{}: no viewpoints", dir.report_json().display())),
        1 => Err(input!(
            "{}: missing or not the track of the report's one viewpoint",
            dir.track_toml().display()
        )),
        _ => Ok(Network::polyline(&pre.track, &positions)
            .context("straight segments through the viewpoints")?),
    }
}
