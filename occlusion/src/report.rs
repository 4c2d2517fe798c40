//! Reports of a culling run: `cull.json` (scripts read it), `cull.md` (the paper's Tables 1–2
//! per variant), the per-tile decision file the database build reads, and the kept/culled
//! atlas image. Everything here returns values or bytes; writing files is the caller's job.
//!
//! Per-tile decision file (`cull_tiles.json`, [`TileDecisions`]): the tile grid, then per run
//! (α, variant) per viewpoint per slab the kept and culled tiles as dense tile indices
//! ([`tracks::TileGrid::tile_index`]: face-major, then rows, then columns). A tile in neither
//! list was empty and never existed.

use serde::{Deserialize, Serialize};
use tracks::{SlabRange, TileGrid};

use crate::cull::{Variant, ViewpointCull};
use crate::oracle::{SlabScore, Visibility};
use crate::shrunk::ShrunkStats;

/// One slab's row in a run (summed over every viewpoint).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SlabRow {
    /// 0 = nearest.
    pub slab: usize,
    pub tiles_before: u64,
    pub tiles_after: u64,
    pub bytes_before: u64,
    pub bytes_after: u64,
    /// With the oracle: culled tiles that were seen, and their seen pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub false_culls: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub false_cull_pixels: Option<u64>,
    /// With the oracle: kept tiles never seen, and tiles seen at all.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kept_never_visible: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub visible_tiles: Option<u64>,
    /// With the oracle: tiles never seen from any oracle position (`tiles_before −
    /// visible_tiles`): the most any method without false culls could cull.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub never_visible: Option<u64>,
}

fn reduction(before: u64, after: u64) -> f64 {
    if before == 0 {
        0.0
    } else {
        100.0 * (before - after.min(before)) as f64 / before as f64
    }
}

impl SlabRow {
    pub fn tile_reduction_percent(&self) -> f64 {
        reduction(self.tiles_before, self.tiles_after)
    }
    pub fn byte_reduction_percent(&self) -> f64 {
        reduction(self.bytes_before, self.bytes_after)
    }
    /// With the oracle: kept tiles per tile seen (1 = exact; the shrunk variant's goal is
    /// ≤ 1.2 on the later slabs).
    pub fn kept_per_seen(&self) -> Option<f64> {
        self.visible_tiles
            .map(|v| self.tiles_after as f64 / v.max(1) as f64)
    }
    /// With the oracle: the tile reduction of a perfect zero-false-cull method.
    pub fn ceiling_percent(&self) -> Option<f64> {
        self.never_visible.map(|n| {
            reduction(
                self.tiles_before,
                self.tiles_before - n.min(self.tiles_before),
            )
        })
    }
}

/// One (α, variant) run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunReport {
    pub alpha: f64,
    pub variant: Variant,
    pub slabs: Vec<SlabRow>,
    /// Culling wall time summed over viewpoints (oracle excluded).
    pub seconds: f64,
    /// The shrunk variant: how its tiles were decided and the tests it cast.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shrunk: Option<ShrunkStats>,
    /// The rendered variant: tiles decided and culled, renders and tests.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rendered: Option<crate::rendered::RenderedStats>,
}

impl RunReport {
    pub fn new(alpha: f64, variant: Variant, slab_count: usize) -> RunReport {
        RunReport {
            alpha,
            variant,
            slabs: (0..slab_count)
                .map(|slab| SlabRow {
                    slab,
                    ..SlabRow::default()
                })
                .collect(),
            seconds: 0.0,
            shrunk: None,
            rendered: None,
        }
    }

    /// The later slabs (all but the nearest) summed into one row (`slab` 1).
    pub fn later_slabs(&self) -> SlabRow {
        let mut t = SlabRow {
            slab: 1,
            ..SlabRow::default()
        };
        let add = |a: &mut Option<u64>, b: Option<u64>| {
            if let Some(b) = b {
                *a.get_or_insert(0) += b;
            }
        };
        for r in self.slabs.iter().skip(1) {
            t.tiles_before += r.tiles_before;
            t.tiles_after += r.tiles_after;
            t.bytes_before += r.bytes_before;
            t.bytes_after += r.bytes_after;
            add(&mut t.false_culls, r.false_culls);
            add(&mut t.false_cull_pixels, r.false_cull_pixels);
            add(&mut t.kept_never_visible, r.kept_never_visible);
            add(&mut t.visible_tiles, r.visible_tiles);
            add(&mut t.never_visible, r.never_visible);
        }
        t
    }

    /// Add one viewpoint's decision and, when the oracle ran, its scores.
    pub fn add(&mut self, v: &ViewpointCull, scores: Option<&[SlabScore]>) {
        for d in &v.slabs {
            if d.slab >= self.slabs.len() {
                self.slabs.resize_with(d.slab + 1, SlabRow::default);
                for (i, r) in self.slabs.iter_mut().enumerate() {
                    r.slab = i;
                }
            }
            let r = &mut self.slabs[d.slab];
            r.tiles_before += d.tiles_before() as u64;
            r.tiles_after += d.kept.len() as u64;
            r.bytes_before += d.bytes_before();
            r.bytes_after += d.bytes_after();
        }
        if let Some(scores) = scores {
            for s in scores {
                if let Some(r) = self.slabs.get_mut(s.slab) {
                    *r.false_culls.get_or_insert(0) += s.false_culls;
                    *r.false_cull_pixels.get_or_insert(0) += s.false_cull_pixels;
                    *r.kept_never_visible.get_or_insert(0) += s.kept_never_visible;
                    *r.visible_tiles.get_or_insert(0) += s.visible_tiles;
                    *r.never_visible.get_or_insert(0) +=
                        (s.kept + s.culled).saturating_sub(s.visible_tiles);
                }
            }
        }
    }
}

/// How the oracle was run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OracleInfo {
    pub per_segment: usize,
    pub face_size: u32,
    /// `geometry` (ray casting) or `depth-renders`.
    pub source: String,
    pub seconds: f64,
}

/// `cull.json`. Keep the names of `runs` and of its fields: scripts read them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CullReport {
    pub viewpoints: usize,
    pub face_size: u32,
    pub tile_size: u32,
    pub slab_ranges: Vec<SlabRange>,
    pub runs: Vec<RunReport>,
    #[serde(default)]
    pub oracle: Option<OracleInfo>,
    /// Loading the inputs, seconds.
    pub load_seconds: f64,
}

/// The paper's table (Tables 1–2) for the runs of one variant, as Markdown.
pub fn paper_table(runs: &[&RunReport]) -> String {
    let slabs = runs.iter().map(|r| r.slabs.len()).max().unwrap_or(0);
    let mut s = String::from("| α | |");
    for k in 0..slabs {
        s += &format!(" Slab {} before | after | reduction |", k + 1);
    }
    s += "\n|---|---|";
    s += &"---:|---:|---:|".repeat(slabs);
    s.push('\n');
    for r in runs {
        s += &format!("| {} | Tiles |", r.alpha);
        for row in &r.slabs {
            s += &format!(
                " {} | {} | {:.1}% |",
                row.tiles_before,
                row.tiles_after,
                row.tile_reduction_percent()
            );
        }
        s += "\n|  | Size (MB) |";
        for row in &r.slabs {
            s += &format!(
                " {:.3} | {:.3} | {:.1}% |",
                row.bytes_before as f64 / 1e6,
                row.bytes_after as f64 / 1e6,
                row.byte_reduction_percent()
            );
        }
        s.push('\n');
        if r.slabs.iter().any(|x| x.false_culls.is_some()) {
            s += "|  | False culls (tiles / px) |";
            for row in &r.slabs {
                s += &format!(
                    " {} | {} | kept unseen {} |",
                    row.false_culls.unwrap_or(0),
                    row.false_cull_pixels.unwrap_or(0),
                    row.kept_never_visible.unwrap_or(0)
                );
            }
            s.push('\n');
            s += "|  | Seen (oracle) → kept, kept ÷ seen |";
            for row in &r.slabs {
                s += &format!(
                    " {} | {} | {:.2}× |",
                    row.visible_tiles.unwrap_or(0),
                    row.tiles_after,
                    row.kept_per_seen().unwrap_or(0.0)
                );
            }
            s.push('\n');
            s += "|  | Never seen (oracle ceiling) |";
            for row in &r.slabs {
                s += &format!(
                    " {} | {} | {:.1}% |",
                    row.tiles_before,
                    row.tiles_before - row.never_visible.unwrap_or(0).min(row.tiles_before),
                    row.ceiling_percent().unwrap_or(0.0)
                );
            }
            s.push('\n');
        }
    }
    s
}

/// `cull.md`: one table per variant, then timings.
pub fn markdown(report: &CullReport) -> String {
    let mut s = format!(
        "# Track-dependent occlusion culling\n\n{} viewpoints, faces {}², tiles {}², slabs {}. \
         Sizes are raw RGBA8 tiles (the paper's Size column).\n",
        report.viewpoints,
        report.face_size,
        report.tile_size,
        report
            .slab_ranges
            .iter()
            .map(|r| r.label())
            .collect::<Vec<_>>()
            .join(", ")
    );
    for v in Variant::ALL {
        let runs: Vec<&RunReport> = report.runs.iter().filter(|r| r.variant == v).collect();
        if runs.is_empty() {
            continue;
        }
        s += &format!("\n## Variant `{}`\n\n", v.name());
        s += &paper_table(&runs);
        for st in runs.iter().filter_map(|r| r.shrunk) {
            s += &format!(
                "\nLater-slab tiles: {} kept as seen from the reference viewpoint, {} kept as \
                 seen from a track point, {} kept without a proof either way, {} culled; {} \
                 shrunk-segment tests and {} free-segment tests.\n",
                st.kept_direct,
                st.kept_seen,
                st.kept_undecided,
                st.culled,
                st.block_tests,
                st.see_tests
            );
        }
        for st in runs.iter().filter_map(|r| r.rendered) {
            s += &format!(
                "\nLater-slab tiles: {} decided, {} culled (every pixel hidden behind a \
                 continuous surface in every depth render); {} depth renders ({:.1} s \
                 waiting for whole renders, included in the time below), {} (pixel, render) \
                 tests.\n",
                st.tiles,
                st.culled,
                st.renders,
                st.render_ms as f64 / 1e3,
                st.tests
            );
        }
    }
    s += "\n## Time and tightness\n\n| α | variant | culling s | later slabs: tiles kept | seen by the oracle | kept ÷ seen | false culls |\n|---|---|---:|---:|---:|---:|---:|\n";
    for r in &report.runs {
        let later = r.later_slabs();
        let cell = |x: Option<u64>| x.map_or("–".to_string(), |v| v.to_string());
        s += &format!(
            "| {} | {} | {:.3} | {} | {} | {} | {} |\n",
            r.alpha,
            r.variant.name(),
            r.seconds,
            later.tiles_after,
            cell(later.visible_tiles),
            later
                .kept_per_seen()
                .map_or("–".to_string(), |x| format!("{x:.2}×")),
            cell(later.false_culls)
        );
    }
    s += &format!("\nLoading inputs: {:.3} s.\n", report.load_seconds);
    if let Some(o) = &report.oracle {
        s += &format!(
            "Oracle: both ends and {} positions per segment at offset fractions (j + 0.618…)/n of \
             its length (never where the shrunk variant samples), {}² per face, from {}: {:.3} s. \
             A false cull is a culled tile with a pixel seen from some oracle position.\n",
            o.per_segment, o.face_size, o.source, o.seconds
        );
    }
    s
}

/// Per-tile decisions of every run (`cull_tiles.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TileDecisions {
    pub grid: TileGrid,
    pub runs: Vec<RunDecisions>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunDecisions {
    pub alpha: f64,
    pub variant: Variant,
    pub viewpoints: Vec<ViewpointDecisions>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ViewpointDecisions {
    pub index: usize,
    pub slabs: Vec<SlabTiles>,
}

/// Dense tile indices kept and culled in one slab.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SlabTiles {
    pub slab: usize,
    pub kept: Vec<u32>,
    pub culled: Vec<u32>,
}

impl ViewpointDecisions {
    pub fn new(index: usize, grid: &TileGrid, v: &ViewpointCull) -> ViewpointDecisions {
        let ids = |ts: &[crate::TileInfo]| {
            let mut x: Vec<u32> = ts.iter().map(|t| grid.tile_index(t.id) as u32).collect();
            x.sort_unstable();
            x
        };
        ViewpointDecisions {
            index,
            slabs: v
                .slabs
                .iter()
                .map(|d| SlabTiles {
                    slab: d.slab,
                    kept: ids(&d.kept),
                    culled: ids(&d.culled),
                })
                .collect(),
        }
    }
}

const EMPTY: [u8; 3] = [24, 24, 24];
const KEPT: [u8; 3] = [60, 200, 80];
const KEPT_UNSEEN: [u8; 3] = [150, 150, 40];
const CULLED: [u8; 3] = [50, 80, 200];
const FALSE_CULL: [u8; 3] = [255, 0, 255];
const GAP: [u8; 3] = [90, 90, 90];

/// An atlas of one run: a row per viewpoint, a column per slab, each cell the six faces side
/// by side at one pixel block per tile. Empty tiles are dark, kept green (olive when the oracle
/// never saw them), culled blue, culled-but-seen magenta. Returns PNG bytes.
pub fn atlas_png(
    grid: &TileGrid,
    runs: &[ViewpointDecisions],
    vis: Option<&[Visibility]>,
) -> Vec<u8> {
    let t = grid.tiles_per_side();
    let s = (96 / t).clamp(1, 8);
    let slabs = runs.iter().map(|v| v.slabs.len()).max().unwrap_or(1).max(1) as u32;
    let cell_w = 6 * (t * s + 1) + 3;
    let cell_h = t * s + 3;
    let (w, h) = (slabs * cell_w, (runs.len() as u32).max(1) * cell_h);
    let mut img = vec![GAP; (w * h) as usize];
    for (row, v) in runs.iter().enumerate() {
        for st in &v.slabs {
            let mut colour = vec![EMPTY; grid.tile_count()];
            for &i in &st.kept {
                colour[i as usize] = KEPT;
            }
            for &i in &st.culled {
                colour[i as usize] = CULLED;
            }
            if let Some(vis) = vis.and_then(|x| x.get(row)) {
                let seen = |i: u32| {
                    grid.tile_at(i as usize).is_some_and(|id| {
                        let tracks::PixelRect { x0, y0, x1, y1, .. } = grid.pixel_rect(id);
                        (y0..y1).any(|y| (x0..x1).any(|x| vis.is_visible(st.slab, id.face, x, y)))
                    })
                };
                for &i in &st.kept {
                    if !seen(i) {
                        colour[i as usize] = KEPT_UNSEEN;
                    }
                }
                for &i in &st.culled {
                    if seen(i) {
                        colour[i as usize] = FALSE_CULL;
                    }
                }
            }
            for (i, c) in colour.iter().enumerate() {
                let Some(id) = grid.tile_at(i) else { continue };
                let x0 =
                    st.slab as u32 * cell_w + 1 + id.face.index() as u32 * (t * s + 1) + id.tx * s;
                let y0 = row as u32 * cell_h + 1 + id.ty * s;
                for y in y0..y0 + s {
                    for x in x0..x0 + s {
                        if x < w && y < h {
                            img[(y * w + x) as usize] = *c;
                        }
                    }
                }
            }
        }
    }
    let bytes: Vec<u8> = img.iter().flatten().copied().collect();
    let mut out = Vec::new();
    use image::ImageEncoder;
    // Encoding into memory only fails on a size mismatch, which the layout rules out.
    image::codecs::png::PngEncoder::new(&mut out)
        .write_image(&bytes, w, h, image::ExtendedColorType::Rgb8)
        .expect("PNG encoding into memory");
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cull::SlabDecision;
    use crate::input::TileInfo;
    use tracks::{Face, TileId};

    fn tile(tx: u32, bytes: u64) -> TileInfo {
        TileInfo {
            id: TileId {
                face: Face::PosX,
                tx,
                ty: 0,
            },
            depth_min: 1.0,
            depth_max: 2.0,
            bytes,
        }
    }

    #[test]
    fn run_sums_and_json_names() {
        let v = ViewpointCull {
            slabs: vec![
                SlabDecision {
                    slab: 0,
                    kept: vec![tile(0, 10), tile(1, 10)],
                    culled: vec![],
                },
                SlabDecision {
                    slab: 1,
                    kept: vec![tile(0, 10)],
                    culled: vec![tile(1, 30)],
                },
            ],
        };
        let mut r = RunReport::new(0.9, Variant::Paper, 2);
        r.add(&v, None);
        r.add(&v, None);
        assert_eq!(r.slabs[1].tiles_before, 4);
        assert_eq!(r.slabs[1].tiles_after, 2);
        assert_eq!(r.slabs[1].bytes_before, 80);
        assert_eq!(r.slabs[1].bytes_after, 20);
        assert_eq!(r.slabs[1].byte_reduction_percent(), 75.0);
        let j = serde_json::to_value(&r).unwrap();
        assert_eq!(j["variant"], "paper");
        assert_eq!(j["slabs"][1]["tiles_after"], 2);
        assert!(j["slabs"][1].get("false_culls").is_none());
        let md = paper_table(&[&r]);
        assert!(md.contains("| 4 | 2 | 50.0% |"), "{md}");
        assert!(!md.contains("Never seen"), "no oracle, no ceiling: {md}");
        // With the oracle: slab 1 has 4 tiles, 1 seen → 3 never seen, a 75 % ceiling.
        let score = |slab, kept, culled, visible| SlabScore {
            slab,
            kept,
            culled,
            visible_tiles: visible,
            ..SlabScore::default()
        };
        let mut o = RunReport::new(1.0, Variant::Conservative, 2);
        for seen in [1, 0] {
            o.add(&v, Some(&[score(0, 2, 0, 2), score(1, 1, 1, seen)]));
        }
        assert_eq!(o.slabs[0].never_visible, Some(0));
        assert_eq!(o.slabs[1].ceiling_percent(), Some(75.0));
        let j = serde_json::to_value(&o).unwrap();
        assert_eq!(j["slabs"][1]["never_visible"], 3);
        let md = paper_table(&[&o]);
        assert!(md.contains("| 4 | 1 | 75.0% |"), "{md}");
        let g = TileGrid::new(8, 4).unwrap();
        let png = atlas_png(&g, &[ViewpointDecisions::new(0, &g, &v)], None);
        assert_eq!(&png[1..4], b"PNG");
    }
}
