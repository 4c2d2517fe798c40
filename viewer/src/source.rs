//! Where reference views come from: a walkthrough database (`manifest.json` + objects, read
//! through `db`) or a prerender directory (`prerender.json` + `samples/`, read
//! through `prerender::store`, meshed here). [`open`] picks by what the directory holds.

use std::path::Path;

use codec::mesh::decode_mesh;
use codec::ptm::{Decoder, Limits};
use db::Database;
use glam::DVec3;
use prerender::store::{self, PrerenderDir};
use rayon::prelude::*;
use tracks::manifest::{PtmRef, TrackEntry};
use tracks::{CubeMap, SlabRange, TileGrid, Track, TrackSet};

use crate::refview::{DenseLayer, LayerMeshing, RefView, TileMesh, ViewTile};
use crate::texture::{dilate_masked, Layer};

/// Errors opening a walkthrough source; each names the file or entry at fault.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SourceError {
    #[error("{0}: neither a database (manifest.json) nor a prerender directory (prerender.json)")]
    Unknown(String),
    #[error(transparent)]
    Db(#[from] db::DbError),
    #[error(transparent)]
    Store(#[from] store::StoreError),
    #[error("{what}: {message}")]
    Format { what: String, message: String },
    #[error("track `{0}` not found (available: {1})")]
    NoTrack(String, String),
    #[error(transparent)]
    View(#[from] crate::refview::ViewError),
}

fn format_err(what: impl Into<String>, message: impl ToString) -> SourceError {
    SourceError::Format {
        what: what.into(),
        message: message.to_string(),
    }
}

/// Reference views along the tracks of a source (one track, or a network of tracks that share
/// viewpoints at junctions), with what is needed to place a camera and to evaluate. A camera
/// is on one track at a time ([`Walkthrough::set_track`]): `track` is that track, and the
/// `s` of its views are their arc lengths along it.
pub struct Walkthrough {
    /// Scene name (`castle`, …) as recorded by the prerenderer.
    pub scene: String,
    /// The track the camera is on.
    pub track: Track,
    /// Every view of the source, by viewpoint id (`views[i].index == i`); on a network the
    /// views of tracks that were not loaded are empty.
    pub views: Vec<RefView>,
    pub slabs: Vec<SlabRange>,
    /// Bytes of payload read (database payloads, each stored payload once however many tiles
    /// use it; or prerender files' decoded size).
    pub bytes: u64,
    /// Every track, and per track its stops: view positions with arc lengths, in order.
    pub tracks: Vec<Track>,
    pub stops: Vec<Vec<(usize, f64)>>,
    /// Position of `track` in `tracks`.
    pub current: usize,
}

impl Walkthrough {
    /// Camera position at arc length `s` (clamped to the track).
    pub fn position_at(&self, s: f64) -> DVec3 {
        self.track.position_at(s)
    }

    /// The camera goes onto track `t`: its views take their arc lengths along it.
    pub fn set_track(&mut self, t: usize) {
        let (Some(track), Some(stops)) = (self.tracks.get(t), self.stops.get(t)) else {
            return;
        };
        self.track = track.clone();
        self.current = t;
        for &(v, s) in stops {
            if let Some(view) = self.views.get_mut(v) {
                view.s = s;
            }
        }
    }

    /// The positions in `views` of the current track's views, in order along it.
    pub fn order(&self) -> Vec<usize> {
        self.stops
            .get(self.current)
            .map(|st| st.iter().map(|x| x.0).collect())
            .unwrap_or_default()
    }

    /// The positions in `views` of the current track's views and their arc lengths.
    pub fn order_and_arcs(&self) -> (Vec<usize>, Vec<f64>) {
        self.stops
            .get(self.current)
            .map(|st| st.iter().copied().unzip())
            .unwrap_or_default()
    }

    /// The frame at arc length `s` of the current track ([`crate::plan::plan_frame_on`]).
    pub fn plan(
        &self,
        camera: &tracks::PerspectiveCamera,
        s: f64,
        budget: crate::plan::DrawBudget,
    ) -> Result<crate::plan::FramePlan, crate::plan::PlanError> {
        crate::plan::plan_frame_on(&self.views, &self.order(), camera, s, budget, &|_| true)
    }

    /// The network of the source's tracks (its junctions, segments and branches).
    pub fn network(&self) -> Result<tracks::network::Network, String> {
        tracks::network::Network::from_parts(
            self.tracks.clone(),
            self.views.iter().map(|v| v.position).collect(),
            self.stops
                .iter()
                .map(|st| {
                    st.iter()
                        .map(|&(viewpoint, s)| tracks::network::Stop { viewpoint, s })
                        .collect()
                })
                .collect(),
        )
    }

    /// A source of one track whose views are `views` in order (their `s` along `track`).
    pub fn single(
        scene: String,
        track: Track,
        views: Vec<RefView>,
        slabs: Vec<SlabRange>,
        bytes: u64,
    ) -> Walkthrough {
        let stops = vec![views.iter().enumerate().map(|(i, v)| (i, v.s)).collect()];
        Walkthrough {
            scene,
            tracks: vec![track.clone()],
            track,
            views,
            slabs,
            bytes,
            stops,
            current: 0,
        }
    }
}

/// How much of each PTM to use: `None` = all levels, `Some(g)` = the first `g` level groups
/// (simulates tiles whose fine levels have not arrived yet); and, on a network, whether the
/// views of every track are decoded (to walk from track to track) or those of the chosen one.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LoadOptions {
    pub level_groups: Option<usize>,
    pub mesh: LayerMeshing,
    pub every_track: bool,
}

/// Open a database or prerender directory.
pub fn open(
    dir: &Path,
    track: Option<&str>,
    opts: LoadOptions,
) -> Result<Walkthrough, SourceError> {
    if dir.join(db::MANIFEST_FILE).is_file() {
        from_database(&Database::open(dir)?, track, opts)
    } else if PrerenderDir::new(dir).report_json().is_file() {
        from_prerender(dir, track, opts.mesh)
    } else {
        Err(SourceError::Unknown(dir.display().to_string()))
    }
}

fn pick_track<'a>(
    entries: &'a [TrackEntry],
    name: Option<&str>,
) -> Result<&'a TrackEntry, SourceError> {
    let names = || {
        entries
            .iter()
            .map(|t| t.name.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    };
    match name {
        Some(n) => entries
            .iter()
            .find(|t| t.name == n)
            .ok_or_else(|| SourceError::NoTrack(n.to_string(), names())),
        None => entries
            .first()
            .ok_or_else(|| SourceError::NoTrack("(any)".into(), names())),
    }
}

fn parse_track(toml: &str, name: &str, source: &str) -> Result<Track, SourceError> {
    let set = TrackSet::parse(toml, source).map_err(|e| format_err(source, e))?;
    set.get(name)
        .or_else(|| set.tracks.first())
        .cloned()
        .ok_or_else(|| SourceError::NoTrack(name.to_string(), set.names().join(", ")))
}

/// Decode the first `groups` level groups of a PTM (all when `None`): the finest decoded
/// image as RGBA and its level.
fn decode_ptm(
    db: &Database,
    ptm: &PtmRef,
    groups: Option<usize>,
    what: &str,
) -> Result<(Vec<u8>, u32, u32, u32), SourceError> {
    let premultiplied = db.top().coarse_levels_premultiplied();
    let count = groups_used(ptm, groups);
    let mut dec = Decoder::new(Limits::default());
    for g in 0..count.min(ptm.levels.len()) {
        let bytes = db.read_level(ptm, g)?;
        dec.push(&bytes).map_err(|e| format_err(what, e))?;
    }
    let level = dec
        .finest_level()
        .ok_or_else(|| format_err(what, "no level decoded"))?;
    let img = dec
        .finest()
        .ok_or_else(|| format_err(what, "no level decoded"))?;
    let mut rgba = image_rgba(img);
    // A coarse level of a format-5 database holds colour × coverage: its outline is drawn in
    // the covered texels' own colour, not darkened by the empty texels beside them.
    if premultiplied && level > 0 {
        db::unpremultiply(&mut rgba);
    }
    Ok((rgba, img.width(), img.height(), level))
}

/// How many of `ptm`'s level groups a load limited to `groups` reads (all for `None`; at
/// least the coarsest).
fn groups_used(ptm: &PtmRef, groups: Option<usize>) -> usize {
    groups
        .unwrap_or(ptm.levels.len())
        .clamp(1, ptm.levels.len().max(1))
        .min(ptm.levels.len())
}

/// Bytes of the level groups of `ptm` that a load limited to `groups` reads.
fn group_bytes(ptm: &PtmRef, groups: Option<usize>) -> u64 {
    ptm.levels
        .iter()
        .take(groups_used(ptm, groups))
        .map(|l| l.len)
        .sum()
}

/// A decoded PTM level as RGBA8 (grey, grey+alpha and RGB expanded).
pub fn image_rgba(img: &codec::ptm::Image) -> Vec<u8> {
    let c = img.channels() as usize;
    img.data()
        .chunks_exact(c.max(1))
        .flat_map(|p| match c {
            1 => [p[0], p[0], p[0], 255],
            2 => [p[0], p[0], p[0], p[1]],
            3 => [p[0], p[1], p[2], 255],
            _ => [p[0], p[1], p[2], p[3]],
        })
        .collect()
}

/// Paste a tile's PTM level `level` (`w × h` RGBA) into its rectangle of a level-0 layer,
/// each texel standing in for `2^level` × `2^level` pixels (nearest). `what` names the tile.
pub fn paste_tile(
    layer: &mut CubeMap<[u8; 4]>,
    grid: TileGrid,
    tile: tracks::TileId,
    (rgba, w, h, level): (&[u8], u32, u32, u32),
    what: &str,
) -> Result<(), SourceError> {
    let tracks::PixelRect { x0, y0, x1, y1, .. } = grid.pixel_rect(tile);
    let scale = 1u32 << level.min(16);
    if w == 0
        || h == 0
        || w * scale < x1 - x0
        || h * scale < y1 - y0
        || rgba.len() < (w * h * 4) as usize
    {
        return Err(format_err(
            what,
            format!(
                "PTM level {level} is {w}x{h}, tile is {}x{}",
                x1 - x0,
                y1 - y0
            ),
        ));
    }
    for y in y0..y1 {
        for x in x0..x1 {
            let (sx, sy) = (((x - x0) / scale).min(w - 1), ((y - y0) / scale).min(h - 1));
            let i = ((sy * w + sx) * 4) as usize;
            *layer.get_mut(tile.face, x, y) = [rgba[i], rgba[i + 1], rgba[i + 2], rgba[i + 3]];
        }
    }
    Ok(())
}

/// A tile's depth mesh from its stored bytes.
pub fn tile_mesh_from_bytes(bytes: &[u8], what: &str) -> Result<TileMesh, SourceError> {
    decode_mesh(bytes).map_err(|e| format_err(what, e))
}

/// The track of a manifest entry.
pub fn manifest_track(entry: &TrackEntry) -> Result<Track, SourceError> {
    parse_track(&entry.track_toml, &entry.name, "manifest.json track_toml")
}

/// Views from a database: tile PTMs pasted into per-slab cube-map layers, meshes decoded.
pub fn from_database(
    db: &Database,
    track: Option<&str>,
    opts: LoadOptions,
) -> Result<Walkthrough, SourceError> {
    let m = db.manifest();
    let entry = pick_track(&m.tracks, track)?;
    let current = m
        .tracks
        .iter()
        .position(|t| t.name == entry.name)
        .unwrap_or(0);
    let tracks: Vec<Track> = m
        .tracks
        .iter()
        .map(manifest_track)
        .collect::<Result<_, _>>()?;
    let all = db::split::unique_viewpoints(m);
    if all.iter().enumerate().any(|(i, v)| v.index != i) {
        return Err(format_err(
            "manifest.json viewpoints",
            "viewpoint ids are not 0..n without gaps",
        ));
    }
    let wanted: std::collections::HashSet<usize> = if opts.every_track {
        all.iter().map(|v| v.index).collect()
    } else {
        entry.viewpoints.iter().map(|v| v.index).collect()
    };
    let n = m.face_size;
    let grid = TileGrid::new(n, m.tile_size)
        .ok_or_else(|| format_err("manifest.json tile_size", m.tile_size))?;
    // Viewpoints on every core (each decodes its own tiles and builds its own layers); the
    // first error in viewpoint order is the one reported.
    // Bytes are counted once per stored payload (a payload may serve several tiles): the
    // ranges read, by object and offset.
    type Read = Vec<(String, u64, u64)>;
    let loaded: Vec<Result<(RefView, Read), SourceError>> = all
        .par_iter()
        .map(|vp| -> Result<(RefView, Read), SourceError> {
            if !wanted.contains(&vp.index) {
                // A viewpoint of a track not loaded: no tiles, 1×1 layers.
                return Ok((
                    RefView::empty(vp.index, vp.s, vp.position, m.tile_size),
                    Vec::new(),
                ));
            }
            let mut read: Read = Vec::new();
            let ptm_read = |p: &PtmRef| {
                let first = p.levels.first().map_or(0, |l| l.offset);
                (
                    p.object.hash.clone(),
                    first,
                    group_bytes(p, opts.level_groups),
                )
            };
            let what = format!("viewpoint {}", vp.index);
            let mut background = CubeMap::filled(n, [0, 0, 0, 0]);
            for (bi, bg) in vp.background.iter().enumerate() {
                let key = format!("{what} background tile {bi}");
                read.push(ptm_read(&bg.ptm));
                let (rgba, w, h, level) = decode_ptm(db, &bg.ptm, opts.level_groups, &key)?;
                paste_tile(&mut background, grid, bg.tile, (&rgba, w, h, level), &key)?;
            }
            let mut layers: Vec<CubeMap<[u8; 4]>> =
                vec![CubeMap::filled(n, [0, 0, 0, 0]); m.slabs.len()];
            let mut tiles = Vec::new();
            for t in vp.tiles.iter().filter(|t| t.kept) {
                let Some(ptm) = &t.ptm else {
                    continue;
                };
                let (mesh_bytes, mesh_at) = match t.mesh_at() {
                    Some((m, None)) => (db.read_object(m)?, (m.hash.clone(), 0)),
                    Some((o, Some(r))) => {
                        (db.read_checked_range(o, r)?, (o.hash.clone(), r.offset))
                    }
                    None => continue,
                };
                let key = tracks::manifest::tile_key(vp.index, t.slab, t.tile);
                let layer = layers.get_mut(t.slab as usize).ok_or_else(|| {
                    format_err(&key, format!("slab {} beyond the manifest's slabs", t.slab))
                })?;
                read.push(ptm_read(ptm));
                read.push((mesh_at.0, mesh_at.1, mesh_bytes.len() as u64));
                let (rgba, w, h, level) = decode_ptm(db, ptm, opts.level_groups, &key)?;
                paste_tile(layer, grid, t.tile, (&rgba, w, h, level), &key)?;
                let mesh = tile_mesh_from_bytes(&mesh_bytes, &key)?;
                let mut vt = ViewTile::new(t.tile, t.slab, mesh, n);
                vt.finest_level = level;
                tiles.push(vt);
            }
            tiles.sort_by_key(|t| (t.slab, grid.tile_index(t.tile)));
            let mut all = vec![Layer::from_rgba(dilate_masked(&background))];
            all.extend(layers.iter().map(|l| Layer::from_rgba(dilate_masked(l))));
            let view = RefView {
                index: vp.index,
                s: vp.s,
                position: vp.position,
                face_size: n,
                tile_size: m.tile_size,
                layers: all,
                tiles,
            };
            Ok((view, read))
        })
        .collect();
    let mut bytes = 0u64;
    let mut seen = std::collections::HashSet::new();
    let mut views = Vec::with_capacity(loaded.len());
    for r in loaded {
        let (view, read) = r?;
        for (object, offset, len) in read {
            if seen.insert((object, offset)) {
                bytes += len;
            }
        }
        views.push(view);
    }
    let stops = m
        .tracks
        .iter()
        .map(|t| t.viewpoints.iter().map(|v| (v.index, v.s)).collect())
        .collect();
    let mut walk = Walkthrough {
        scene: m.scene.clone(),
        track: tracks[current].clone(),
        views,
        slabs: m.slabs.clone(),
        bytes,
        tracks,
        stops,
        current,
    };
    walk.set_track(current);
    Ok(walk)
}

/// Views from a prerender directory: per-slab layers (`slab_K/`) meshed with `params`; the
/// background is the colour where the depth is infinite. A directory without slab layers is
/// one slab holding everything.
pub fn from_prerender(
    dir: &Path,
    track: Option<&str>,
    params: LayerMeshing,
) -> Result<Walkthrough, SourceError> {
    let pd = PrerenderDir::new(dir);
    let report = pd.read_report()?;
    let toml = std::fs::read_to_string(pd.track_toml())
        .map_err(|e| format_err(pd.track_toml().display().to_string(), e))?;
    let source = pd.track_toml().display().to_string();
    // A network (`all`): every track of the file, the viewpoints numbered over it.
    let network = if report.track == "all" {
        let set = TrackSet::parse(&toml, &source).map_err(|e| format_err(&source, e))?;
        Some(tracks::network::Network::new(set.tracks).map_err(|e| format_err(&source, e))?)
    } else {
        None
    };
    let track = match &network {
        Some(net) => {
            let t = match track {
                Some(n) => net.track_index(n).ok_or_else(|| {
                    let names: Vec<&str> = net.tracks.iter().map(|t| t.name.as_str()).collect();
                    SourceError::NoTrack(n.to_string(), names.join(", "))
                })?,
                None => 0,
            };
            net.tracks[t].clone()
        }
        None => parse_track(&toml, track.unwrap_or(&report.track), &source)?,
    };
    let mut views = Vec::new();
    let mut bytes = 0u64;
    for vp in &report.viewpoints {
        let i = vp.index;
        let color = store::read_rgb_png(&pd.color_png(i))?;
        let depth = store::read_depth_exr(&pd.depth_exr(i))?;
        let n = color.face_size();
        let background = CubeMap::from_fn(n, |f, x, y| {
            let c = color.get(f, x, y);
            let sky = !depth.get(f, x, y).is_finite();
            [c[0], c[1], c[2], if sky { 255 } else { 0 }]
        });
        let mut slab_maps = Vec::new();
        for k in 0..report.slabs.len() {
            let c = store::read_rgba_png(&pd.slab_color_png(i, k))?;
            let d = store::read_depth_exr(&pd.slab_depth_exr(i, k))?;
            slab_maps.push((c, d));
        }
        if slab_maps.is_empty() {
            let c = CubeMap::from_fn(n, |f, x, y| {
                let p = color.get(f, x, y);
                [
                    p[0],
                    p[1],
                    p[2],
                    if depth.get(f, x, y).is_finite() {
                        255
                    } else {
                        0
                    },
                ]
            });
            slab_maps.push((c, depth.clone()));
        }
        bytes += slab_maps.len() as u64 * 8 * (6 * n as u64 * n as u64);
        let dense: Vec<DenseLayer<'_>> = slab_maps
            .iter()
            .map(|(c, d)| DenseLayer { color: c, depth: d })
            .collect();
        let tile = n.max(1).next_power_of_two().min(32);
        views.push(RefView::from_layers(
            i,
            vp.s,
            vp.position,
            tile,
            params,
            &background,
            &dense,
        )?);
    }
    let slabs = if report.slabs.is_empty() {
        vec![SlabRange {
            near: 0.0,
            far: f64::INFINITY,
        }]
    } else {
        report.slabs.clone()
    };
    let Some(net) = network else {
        return Ok(Walkthrough::single(
            report.scene.clone(),
            track,
            views,
            slabs,
            bytes,
        ));
    };
    if views.len() != net.viewpoints.len() {
        return Err(format_err(
            pd.report_json().display().to_string(),
            format!(
                "{} viewpoints, its tracks' network has {}",
                views.len(),
                net.viewpoints.len()
            ),
        ));
    }
    let current = net.track_index(&track.name).unwrap_or(0);
    let mut walk = Walkthrough {
        scene: report.scene.clone(),
        track,
        views,
        slabs,
        bytes,
        stops: net
            .stops
            .iter()
            .map(|st| st.iter().map(|x| (x.viewpoint, x.s)).collect())
            .collect(),
        tracks: net.tracks,
        current,
    };
    walk.set_track(current);
    Ok(walk)
}
