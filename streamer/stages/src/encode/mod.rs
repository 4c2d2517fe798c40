//! The encode stage: every sample's kept tiles (PTM textures, depth meshes) and background
//! into the database's objects, ACH per segment, the manifest last, and the baseline the
//! database is weighed against; sizes, counts and timings go into the [`BuildReport`].
//!
//! The tiles' own PTM and mesh objects are staged in the work directory (`WORK/encode/`,
//! with one record per sample, `encode/NNNN.json`, [`EncodedSample`]); each viewpoint's pack
//! in the database is made from them, so the database holds only what its manifest refers
//! to. A sample whose record has the same key and whose objects are all there is not encoded
//! again.

mod report;
mod sample;

use std::path::{Path, PathBuf};
use std::time::Instant;

use codec::mesh::MeshCoding;
use codec::ptm::{self, EncodeOptions};
use db::ach::{segment_ach, AchParams, AchTile, SegmentEnd};
use db::DbWriter;
use occlusion::report::TileDecisions;
use occlusion::Variant;
use prerender::store::{self, PrerenderDir, PrerenderReport};
use serde::{Deserialize, Serialize};
use slabs::io as sio;
use slabs::report::SlabsReport;
use tracks::manifest::{
    Manifest, SegmentEntry, TileEntry, TrackEntry, ViewpointEntry, MANIFEST_VERSION,
};
use tracks::{CubeMap, TileGrid, TrackSet};

pub use report::{BuildConfig, BuildReport, Sizes, SlabRow};
pub use sample::EncodedSample;

use self::sample::{all_present, crop, encode_sample, fnv64, Coding};
use crate::error::{input, parameter, Context, Result};
use crate::progress::{BarKind, Reporter};

/// How the tiles are coded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EncodeParams {
    /// How PTM level groups are coded.
    pub method: ptm::Method,
    /// zstd level of the PTM groups with [`ptm::Method::Zstd`].
    pub zstd_level: i32,
    /// Lossy textures: the largest error of a colour sample at every PTM level (0 =
    /// lossless; needs [`ptm::Method::Arith`]).
    pub lossy_near: u8,
    /// Bound on the meshes' depth quantisation, pixels of parallax at the track's largest
    /// baseline (0.001 to 10).
    pub depth_error_px: f64,
    /// Finest texture levels left out.
    pub drop_levels: u32,
    /// ACH: viewpoints sampled per segment, pixels per side of each camera.
    pub ach: AchParams,
}

impl Default for EncodeParams {
    fn default() -> Self {
        EncodeParams {
            method: ptm::Method::Arith,
            zstd_level: 19,
            lossy_near: 0,
            depth_error_px: 0.05,
            drop_levels: 0,
            ach: AchParams::default(),
        }
    }
}

impl EncodeParams {
    fn check(&self) -> Result<()> {
        if self.lossy_near > ptm::MAX_NEAR
            || (self.lossy_near > 0 && self.method != ptm::Method::Arith)
        {
            return Err(parameter!(
                "--lossy-near {}: at most {} and only with --ptm-method arith",
                self.lossy_near,
                ptm::MAX_NEAR
            ));
        }
        if !(0.001..=10.0).contains(&self.depth_error_px) {
            return Err(parameter!(
                "--depth-error-px {}: expected 0.001 to 10 pixels of parallax",
                self.depth_error_px
            ));
        }
        Ok(())
    }
}

/// The culling the tiles got.
#[derive(Clone, Debug, PartialEq)]
pub struct Culling {
    /// The kept/culled decisions of the one run used; none keeps every non-empty tile.
    pub decisions: Option<TileDecisions>,
    /// The variant asked for, and its α.
    pub variant: Option<Variant>,
    pub alpha: f64,
    /// In words, for the report.
    pub summary: String,
}

/// Where the encode stage reads and writes.
#[derive(Clone, Debug, PartialEq)]
pub struct EncodeDirs {
    /// The database.
    pub out: PathBuf,
    /// The work directory: `prerender/` (after the slabs and cull stages), `encode/` and
    /// `baseline.json`.
    pub work: PathBuf,
}

fn stage(progress: &Reporter, n: usize, what: &str) {
    progress.message(&format!("[{n}/6] {what}"));
}

/// Encode, ACH, the manifest and the baseline, into `report`.
pub fn run(
    dirs: &EncodeDirs,
    params: &EncodeParams,
    tiling: &SlabsReport,
    culling: &Culling,
    report: &mut BuildReport,
    progress: &Reporter,
) -> Result<()> {
    let m = crate::cost::Meter::start();
    stage(progress, 4, "encode (PTM + meshes)");
    let dir = PrerenderDir::new(dirs.work.join("prerender"));
    let mut pre: PrerenderReport = dir.read_report().context("reading the prerender report")?;
    report.track = pre.track.clone();
    if pre.slabs.is_empty() {
        // A resumed prerender rewrites its report without the slabs; the layers know them.
        if let Some(m) = pre
            .viewpoints
            .first()
            .and_then(|v| dir.layers_meta(v.index))
        {
            pre.slabs = m.slabs;
        }
    }
    if pre.slabs.is_empty() {
        return Err(input!(
            "{}: no slab layers after the slabs stage",
            dir.report_json().display()
        ));
    }
    params.check()?;
    // The tiles' own PTM and mesh objects, which the viewpoints' packs replace, stay in the
    // work directory: the database holds only what its manifest refers to.
    let mut writer = DbWriter::create(&dirs.out)?.with_stage(&dirs.work.join("encode"))?;
    if !writer.leftovers_removed.is_empty() {
        progress.message(&format!(
            "      removed {} temporary file(s) of an interrupted build",
            writer.leftovers_removed.len()
        ));
    }
    let (viewpoints, grid) = encode_all(
        &dirs.work,
        &dir,
        &pre,
        params,
        tiling,
        culling,
        &mut writer,
        report,
        progress,
    )?;
    report.stage_done("encode", m);
    let m = crate::cost::Meter::start();
    stage(progress, 5, "ACH per segment");
    let net = crate::network::network_of(&dir, &pre)?;
    let segments = ach(
        &dir,
        &net,
        &viewpoints,
        &grid,
        pre.slabs.len(),
        params.ach,
        progress,
    )?;
    report.stage_done("ach", m);
    stage(progress, 6, "manifest");
    manifest(
        &pre,
        &net,
        &grid,
        culling,
        viewpoints,
        segments,
        &mut writer,
    )?;
    report.objects_written = writer.objects_written;
    report.objects_reused = writer.objects_reused;
    report.sizes.payloads_shared = writer.payloads_shared;
    report.sizes.bytes_shared = writer.bytes_shared;
    drop(writer);
    // Objects an earlier build wrote here that the new manifest does not reference (another
    // format or setting): removed, so the directory is the database and its size is true.
    // A database that is not intact (a damaged file left by something else) is not pruned;
    // the build still succeeds and says so (`railview verify` names the file).
    match db::prune(&dirs.out) {
        Ok(pruned) => {
            if pruned.objects > 0 {
                progress.message(&format!(
                    "      removed {} object(s), {} bytes, of an earlier build that the \
                     manifest no longer references",
                    pruned.objects, pruned.bytes
                ));
            }
            report.objects_pruned = pruned.objects as u64;
        }
        Err(e) => progress.message(&format!(
            "      objects of earlier builds not removed: {e} (see `railview verify {}`)",
            dirs.out.display()
        )),
    }
    report.sizes.database_objects = walk_size(&dirs.out.join("objects"));

    // The baseline, from the same prerender directory.
    let t = Instant::now();
    let base = baseline(&dir, &pre, &dirs.work)?;
    let sizes = &mut report.sizes;
    sizes.baseline_colour_png = base.iter().map(|b| b.colour_png).sum();
    sizes.baseline_depth_png16 = base.iter().map(|b| b.depth_png16).sum();
    sizes.baseline = sizes.baseline_colour_png + sizes.baseline_depth_png16;
    sizes.db_over_baseline = sizes.database_objects as f64 / sizes.baseline.max(1) as f64;
    report
        .seconds
        .push(("baseline".into(), t.elapsed().as_secs_f64()));
    Ok(())
}

/// Every sample encoded (or its record reused); the sizes per slab into `report`.
#[expect(
    clippy::too_many_arguments,
    reason = "the stage's inputs, each from a different stage, and its outputs"
)]
fn encode_all(
    work: &Path,
    dir: &PrerenderDir,
    pre: &PrerenderReport,
    params: &EncodeParams,
    tiling: &SlabsReport,
    culling: &Culling,
    writer: &mut DbWriter,
    report: &mut BuildReport,
    progress: &Reporter,
) -> Result<(Vec<ViewpointEntry>, TileGrid)> {
    let opts = EncodeOptions {
        method: params.method,
        zstd_level: params.zstd_level,
        near: params.lossy_near,
        ..EncodeOptions::default()
    };
    let mesh_coding = MeshCoding::for_parallax(
        tiling.face_size,
        tiling.mesh_params.baseline_m,
        params.depth_error_px,
    );
    let prerender::sky::TrackSky {
        sky,
        source: sky_source,
    } = prerender::sky::load_or_assemble(dir, pre).context("the track's complete sky")?;
    report.sky = format!("{sky_source:?}").to_lowercase();
    let sky_digest = sky.as_ref().map_or(0, |s| {
        fnv64(&s.as_slice().iter().flatten().copied().collect::<Vec<u8>>())
    });
    let coding = Coding {
        opts: &opts,
        mesh: &mesh_coding,
        drop_levels: params.drop_levels,
        sky: sky.as_ref(),
    };
    // `db{TOP_VERSION}`: a format's rule on the PTMs' content (format 5 clears the colour
    // under the mask) re-encodes samples encoded under another; so does any other knob, and
    // tiles meshed with other parameters.
    let key = format!(
        "ptm-v{} db{} {:?} zstd{} near{} mesh-v{} depth{} tiles:{}/{}/{:?}/{:?} cull:{} drop:{} sky:{:016x}/{}",
        ptm::FORMAT_VERSION,
        db::TOP_VERSION,
        params.method,
        params.zstd_level,
        params.lossy_near,
        codec::mesh::MESH_VERSION,
        params.depth_error_px,
        tiling.face_size,
        tiling.tile_size,
        tiling.mesh_kind,
        tiling.mesh_params,
        culling.summary,
        params.drop_levels,
        sky_digest,
        db::SKY_BEHIND_ALPHA
    );
    let enc_dir = work.join("encode");
    let mut viewpoints = Vec::new();
    let mut grid = None;
    let nslabs = pre.slabs.len();
    let mut rows: Vec<SlabRow> = (0..nslabs)
        .map(|slab| SlabRow {
            slab,
            ..SlabRow::default()
        })
        .collect();
    let b = progress.bar(pre.viewpoints.len() as u64, "encoding", BarKind::Steps);
    for vp in &pre.viewpoints {
        let path = enc_dir.join(format!("{:04}.json", vp.index));
        let tiles_bytes = std::fs::read(sio::tiles_json(dir, vp.index))
            .with_context(|| format!("sample {}: reading its tiles file", vp.index))?;
        let key = format!("{key} tiles:{:016x}", fnv64(&tiles_bytes));
        let cached: Option<EncodedSample> = store::read_json(&path)
            .ok()
            .filter(|c: &EncodedSample| c.key == key && all_present(writer.stage_root(), &c.entry));
        let sample = match cached {
            Some(c) => c,
            None => {
                let decisions = culling.decisions.as_ref();
                let s = encode_sample(dir, vp, pre, decisions, &coding, writer, &key)?;
                store::write_json(&path, &s)?;
                // The manifest is always assembled from these records, so a resumed build
                // gives the same bytes (JSON float parsing is not always bit-exact).
                store::read_json(&path)?
            }
        };
        let (file, _) = sio::read_tiles(dir, vp.index)?;
        grid = Some(file.grid);
        add_sample(&sample, &mut rows, report);
        viewpoints.push(sample.entry);
        b.inc(1);
    }
    b.finish();
    let grid = grid.context("no viewpoints")?;
    report.tile_size = grid.tile_size;
    report.samples = viewpoints.len();
    let face_px = 6 * (pre.face_size as u64).pow(2) * 4;
    report.sizes.panoramas_rgba = face_px * viewpoints.len() as u64;
    report.sizes.slab_layers_rgba = face_px * (viewpoints.len() * nslabs) as u64;
    report.sizes.nonempty_tiles_rgba = rows.iter().map(|r| r.rgba_nonempty).sum();
    report.sizes.kept_tiles_rgba = rows.iter().map(|r| r.rgba_kept).sum();
    report.sizes.kept_tiles_ptm = rows.iter().map(|r| r.ptm_kept).sum();
    report.slabs = rows;
    Ok((viewpoints, grid))
}

/// One sample's tiles and bytes, counted per slab and in the report's sizes.
fn add_sample(sample: &EncodedSample, rows: &mut [SlabRow], report: &mut BuildReport) {
    for (k, row) in rows.iter_mut().enumerate() {
        row.tiles_nonempty += sample.tiles_nonempty.get(k).copied().unwrap_or(0);
        row.rgba_nonempty += sample.rgba_nonempty.get(k).copied().unwrap_or(0);
        row.rgba_kept += sample.rgba_kept.get(k).copied().unwrap_or(0);
    }
    for tile in &sample.entry.tiles {
        let row = &mut rows[tile.slab as usize];
        if tile.kept {
            row.tiles_kept += 1;
            row.ptm_kept += tile.ptm.as_ref().map_or(0, |p| p.object.size);
            report.sizes.meshes += tile.mesh.as_ref().map_or(0, |m| m.size);
            report.sizes.kept_tiles += 1;
            report.sizes.meshes_count += u64::from(tile.mesh.is_some());
        }
    }
    report.sizes.backgrounds_ptm += sample
        .entry
        .background
        .iter()
        .map(|b| b.ptm.object.size)
        .sum::<u64>();
}

/// ACH of every segment of the network (in the network's order), from the kept tiles' depth
/// at both ends; `viewpoints` by id.
fn ach(
    dir: &PrerenderDir,
    net: &tracks::network::Network,
    viewpoints: &[ViewpointEntry],
    grid: &TileGrid,
    nslabs: usize,
    params: AchParams,
    progress: &Reporter,
) -> Result<Vec<SegmentEntry>> {
    let mut segments = Vec::new();
    let b = progress.bar(net.segments.len() as u64, "ACH", BarKind::Steps);
    let mut depth_cache: Vec<(usize, Vec<CubeMap<f32>>)> = Vec::new();
    for sg in &net.segments {
        let (a, z) = (&viewpoints[sg.from], &viewpoints[sg.to]);
        for v in [a, z] {
            if !depth_cache.iter().any(|(i, _)| *i == v.index) {
                let maps = (0..nslabs)
                    .map(|k| store::read_depth_exr(&dir.slab_depth_exr(v.index, k)))
                    .collect::<std::result::Result<Vec<_>, _>>()?;
                depth_cache.push((v.index, maps));
            }
        }
        depth_cache.retain(|(i, _)| *i == a.index || *i == z.index);
        let maps_of = |vi: usize| {
            &depth_cache
                .iter()
                .find(|(i, _)| *i == vi)
                .expect("both ends are cached above")
                .1
        };
        let crops: Vec<(usize, &TileEntry, Vec<f32>)> = [a, z]
            .iter()
            .flat_map(|v| v.tiles.iter().filter(|t| t.kept).map(move |t| (v.index, t)))
            .map(|(vi, t)| (vi, t, crop(&maps_of(vi)[t.slab as usize], grid, t.tile)))
            .collect();
        let tiles: Vec<AchTile> = crops
            .iter()
            .map(|(vi, t, d)| {
                let tracks::PixelRect { x0, y0, x1, y1, .. } = grid.pixel_rect(t.tile);
                AchTile {
                    viewpoint: *vi,
                    slab: t.slab,
                    tile: t.tile,
                    face_size: grid.face_size,
                    x0,
                    y0,
                    width: x1 - x0,
                    height: y1 - y0,
                    depth: d,
                }
            })
            .collect();
        let end = |v: &ViewpointEntry| SegmentEnd {
            index: v.index,
            position: v.position,
        };
        segments.push(SegmentEntry {
            from: a.index,
            to: z.index,
            ach: segment_ach(end(a), end(z), &tiles, params),
        });
        b.inc(1);
    }
    b.finish();
    Ok(segments)
}

/// The manifest, last: the database is complete once it is written. One track entry per
/// track of the network, listing its stops' viewpoint entries (at its own arc lengths) and
/// its segments with their ACH lists (`segments` in the network's order).
fn manifest(
    pre: &PrerenderReport,
    net: &tracks::network::Network,
    grid: &TileGrid,
    culling: &Culling,
    viewpoints: Vec<ViewpointEntry>,
    segments: Vec<SegmentEntry>,
    writer: &mut DbWriter,
) -> Result<()> {
    let decided = culling.decisions.as_ref();
    // Each entry moves into the last track that lists it and is cloned only for the others
    // (a junction's viewpoint): a copy of every tile entry was the build's peak (town-10).
    let seg_ids =
        |ti: usize| (0..net.track_segments(ti).len()).filter_map(move |k| net.segment_id(ti, k));
    let mut vp_uses = vec![0usize; viewpoints.len()];
    let mut seg_uses = vec![0usize; segments.len()];
    for (ti, stops) in net.stops.iter().enumerate() {
        for st in stops {
            if let Some(u) = vp_uses.get_mut(st.viewpoint) {
                *u += 1;
            }
        }
        for e in seg_ids(ti) {
            if let Some(u) = seg_uses.get_mut(e) {
                *u += 1;
            }
        }
    }
    let mut viewpoints = Last::new(viewpoints, vp_uses);
    let mut segments = Last::new(segments, seg_uses);
    let mut tracks = Vec::with_capacity(net.tracks.len());
    for (ti, t) in net.tracks.iter().enumerate() {
        let one = TrackSet {
            tracks: vec![t.clone()],
        };
        let mut entries = Vec::with_capacity(net.stops[ti].len());
        for st in &net.stops[ti] {
            let entry = viewpoints
                .get(st.viewpoint)
                .with_context(|| format!("viewpoint {}: no entry encoded", st.viewpoint))?;
            entries.push(ViewpointEntry { s: st.s, ..entry });
        }
        let segs = seg_ids(ti)
            .map(|e| {
                segments
                    .get(e)
                    .with_context(|| format!("segment {e}: no ACH entry"))
            })
            .collect::<Result<Vec<_>>>()?;
        tracks.push(TrackEntry {
            name: t.name.clone(),
            track_toml: one.to_toml(),
            length: t.length(),
            viewpoints: entries,
            segments: segs,
        });
    }
    let manifest = Manifest {
        version: MANIFEST_VERSION,
        scene: pre.scene.clone(),
        face_size: pre.face_size,
        tile_size: grid.tile_size,
        slabs: pre.slabs.clone(),
        cull_alpha: decided.map(|_| culling.alpha),
        cull_variant: decided.and(culling.variant).map(|v| v.name().to_string()),
        tracks,
    };
    writer.finish_owned(manifest)?;
    Ok(())
}

/// Values handed out as often as they were counted: cloned until the last, which is moved.
struct Last<T> {
    items: Vec<Option<T>>,
    uses: Vec<usize>,
}

impl<T: Clone> Last<T> {
    fn new(items: Vec<T>, uses: Vec<usize>) -> Last<T> {
        Last {
            items: items.into_iter().map(Some).collect(),
            uses,
        }
    }

    /// Item `i` (`None` beyond the items, or once its counted uses are spent).
    fn get(&mut self, i: usize) -> Option<T> {
        let u = self.uses.get_mut(i)?;
        *u = u.checked_sub(1)?;
        let slot = self.items.get_mut(i)?;
        if *u == 0 {
            slot.take()
        } else {
            slot.clone()
        }
    }
}

/// What `WORK/baseline.json` keeps: the baseline per viewpoint and the BLAKE3 of the files it
/// was measured from.
#[derive(Serialize, Deserialize)]
struct BaselineCache {
    key: String,
    panoramas: Vec<db::baseline::PanoramaBaseline>,
}

/// The baseline of every reference panorama of the prerender directory: measured on every
/// core, kept in `WORK/baseline.json` while the colour and depth files stay the same.
fn baseline(
    dir: &PrerenderDir,
    pre: &PrerenderReport,
    work: &Path,
) -> Result<Vec<db::baseline::PanoramaBaseline>> {
    let mut h = blake3::Hasher::new();
    for vp in &pre.viewpoints {
        for path in [dir.color_png(vp.index), dir.depth_exr(vp.index)] {
            let bytes =
                std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
            h.update(&bytes);
        }
    }
    let key = format!("baseline-v1 {}", h.finalize().to_hex());
    let path = work.join("baseline.json");
    if let Ok(c) = store::read_json::<BaselineCache>(&path) {
        if c.key == key && c.panoramas.len() == pre.viewpoints.len() {
            return Ok(c.panoramas);
        }
    }
    let panoramas = db::baseline::measure(pre.viewpoints.len(), |k| {
        let i = pre.viewpoints[k].index;
        let colour = store::read_rgb_png(&dir.color_png(i))?;
        let depth = store::read_depth_exr(&dir.depth_exr(i))?;
        Ok::<_, crate::Error>((colour, depth))
    })?;
    store::write_json(
        &path,
        &BaselineCache {
            key,
            panoramas: panoramas.clone(),
        },
    )?;
    Ok(panoramas)
}

/// Bytes of the files under `dir`.
pub fn walk_size(dir: &Path) -> u64 {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return 0;
    };
    rd.filter_map(std::result::Result::ok)
        .map(|e| {
            let p = e.path();
            if p.is_dir() {
                walk_size(&p)
            } else {
                e.metadata().map_or(0, |m| m.len())
            }
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::Last;

    #[test]
    fn last_clones_until_the_last_use_then_moves_and_then_has_nothing() {
        let mut l = Last::new(vec![String::from("a"), String::from("b")], vec![2, 1]);
        assert_eq!(l.get(0).as_deref(), Some("a"));
        assert_eq!(l.items[0].as_deref(), Some("a"));
        assert_eq!(l.get(0).as_deref(), Some("a"));
        assert!(l.items[0].is_none());
        assert_eq!(l.get(0), None);
        assert_eq!(l.get(1).as_deref(), Some("b"));
        assert_eq!(l.get(2), None);
    }
}
