//! The network of tracks a prerender directory was rendered along: every track of its
//! `track.toml` when the report names [`ALL_TRACKS`], else the one it names. Every stage
//! after `prerender` walks the same graph: its viewpoints in the report's order, its
//! segments for culling, its junctions for the manifest.

use prerender::store::{PrerenderDir, PrerenderReport};
use tracks::network::Network;
use tracks::{ReferenceViewpoint, Track, TrackSet};

use crate::error::{input, parameter, Context, Result};

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

/// The tracks a stage renders: every track of `set` when `name` is [`ALL_TRACKS`], else the
/// one named. With the name `None`, the set's only track, its track `main`, or (`first`) its
/// first.
pub fn choose_tracks(
    set: &TrackSet,
    name: Option<&str>,
    source: &str,
    first: bool,
) -> Result<(String, Vec<Track>)> {
    match name {
        Some(ALL_TRACKS) => {
            if set.tracks.is_empty() {
                return Err(input!("{source}: no [[track]]"));
            }
            Ok((ALL_TRACKS.to_string(), set.tracks.clone()))
        }
        Some(n) => set
            .get(n)
            .map(|t| (t.name.clone(), vec![t.clone()]))
            .ok_or_else(|| {
                parameter!(
                    "{source}: no track `{n}` (tracks: {}; `{ALL_TRACKS}` for every one)",
                    set.names().join(", ")
                )
            }),
        None => {
            let t = match set.tracks.as_slice() {
                [one] => Some(one),
                _ if first => set.tracks.first(),
                _ => set.get("main"),
            };
            t.map(|t| (t.name.clone(), vec![t.clone()])).ok_or_else(|| {
                parameter!(
                    "{source}: holds several tracks ({}) and none is named `main`: name one, or \
                     `{ALL_TRACKS}` for every one",
                    set.names().join(", ")
                )
            })
        }
    }
}

/// The reference viewpoints of a network in the report's form: its global ids, each at its
/// arc length on the first track that stops there.
pub fn network_viewpoints(net: &Network) -> Vec<ReferenceViewpoint> {
    let mut s = vec![f64::NAN; net.viewpoints.len()];
    for stop in net.stops.iter().flatten() {
        if s[stop.viewpoint].is_nan() {
            s[stop.viewpoint] = stop.s;
        }
    }
    net.viewpoints
        .iter()
        .enumerate()
        .map(|(index, &position)| ReferenceViewpoint {
            index,
            s: if s[index].is_nan() { 0.0 } else { s[index] },
            position,
        })
        .collect()
}

/// The network of `tracks` and its viewpoints, or a message naming the file and line of the
/// near miss that stops it.
pub fn network_of_tracks(tracks: Vec<Track>) -> Result<(Network, Vec<ReferenceViewpoint>)> {
    let net = Network::new(tracks)?;
    let vps = network_viewpoints(&net);
    Ok((net, vps))
}
