//! The `slabs` report: `slabs.json` for scripts, `slabs.md` for people, `histogram.png`.

use serde::{Deserialize, Serialize};
use tracks::SlabRange;

use crate::boundaries::{Candidate, CriterionReport, SlabChoice};
use crate::histogram::DepthHistogram;
use crate::mesh::{MeshParams, MeshStats};
use crate::tiles::{MeshKind, SampleTiles};

/// Mesh totals of one slab over every tile of every viewpoint.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MeshTotals {
    pub triangles: usize,
    pub vertices: usize,
    pub uncovered_pixels: usize,
    /// Worst tile's maximum error, parallax pixels at the track's largest baseline.
    pub max_error_px: f64,
    /// Mean over tiles of the per-tile mean error, weighted by covered pixels.
    pub mean_error_px: f64,
    #[serde(skip)]
    weighted_sum: f64,
    #[serde(skip)]
    covered: usize,
}

impl MeshTotals {
    fn add(&mut self, s: &MeshStats) {
        self.triangles += s.triangles;
        self.vertices += s.vertices;
        self.uncovered_pixels += s.uncovered_pixels;
        self.max_error_px = self.max_error_px.max(s.max_error_px);
        self.weighted_sum += s.mean_error_px * s.covered_pixels as f64;
        self.covered += s.covered_pixels;
        self.mean_error_px = if self.covered > 0 {
            self.weighted_sum / self.covered as f64
        } else {
            0.0
        };
    }
}

/// One slab in `slabs.json` (names are read by scripts: keep them).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SlabSummary {
    pub near: f64,
    /// `null` for infinity.
    #[serde(serialize_with = "ser_far", deserialize_with = "de_far")]
    pub far: f64,
    /// Tiles over all viewpoints before empty-tile removal.
    pub tiles_before: usize,
    /// Tiles with at least one opaque pixel.
    pub tiles_after: usize,
    pub opaque_pixels: u64,
    /// Pixels of the kept tiles.
    pub pixels: u64,
    /// Raw RGBA8 bytes of the kept tiles (before PTM coding).
    pub texture_bytes: u64,
    /// Bytes of the kept meshes in `tiles.bin`.
    pub mesh_bytes: u64,
    #[serde(default)]
    pub grid_mesh: MeshTotals,
    #[serde(default)]
    pub adaptive_mesh: MeshTotals,
    /// The criterion's numbers at this slab's near boundary (none for the first slab or a
    /// manual list).
    pub boundary: Option<Candidate>,
}

fn ser_far<S: serde::Serializer>(far: &f64, s: S) -> Result<S::Ok, S::Error> {
    if far.is_finite() {
        s.serialize_f64(*far)
    } else {
        s.serialize_none()
    }
}

fn de_far<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::INFINITY))
}

/// `slabs.json`. Read back, a field the file lacks (a report of an earlier version) takes its
/// default.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SlabsReport {
    /// Nearest first.
    pub slabs: Vec<SlabSummary>,
    pub criterion: CriterionReport,
    pub histogram: DepthHistogram,
    pub samples: usize,
    pub face_size: u32,
    pub tile_size: u32,
    pub mesh_params: MeshParams,
    pub mesh_kind: MeshKind,
    pub seconds: f64,
}

impl SlabsReport {
    /// An empty report for `choice`, to which samples are added.
    pub fn new(
        choice: &SlabChoice,
        face_size: u32,
        tile_size: u32,
        mesh_params: MeshParams,
        mesh_kind: MeshKind,
    ) -> SlabsReport {
        SlabsReport {
            slabs: choice
                .slabs
                .iter()
                .map(|r| SlabSummary {
                    near: r.near,
                    far: r.far,
                    tiles_before: 0,
                    tiles_after: 0,
                    opaque_pixels: 0,
                    pixels: 0,
                    texture_bytes: 0,
                    mesh_bytes: 0,
                    grid_mesh: MeshTotals::default(),
                    adaptive_mesh: MeshTotals::default(),
                    boundary: boundary_of(&choice.criterion, r),
                })
                .collect(),
            criterion: choice.criterion.clone(),
            histogram: choice.histogram.clone(),
            samples: 0,
            face_size,
            tile_size,
            mesh_params,
            mesh_kind,
            seconds: 0.0,
        }
    }

    /// Add one viewpoint's tiles (layer `k` counts towards slab `k`).
    pub fn add_sample(&mut self, tiles: &SampleTiles) {
        self.samples += 1;
        for l in &tiles.layers {
            let Some(s) = self.slabs.get_mut(l.slab) else {
                continue;
            };
            s.tiles_before += l.tiles_before;
            s.tiles_after += l.tiles.len();
            for t in &l.tiles {
                s.opaque_pixels += t.opaque_pixels as u64;
                s.pixels += t.pixels as u64;
                s.texture_bytes += 4 * t.pixels as u64;
                s.mesh_bytes += 12 * t.mesh.vertices.len() as u64 + 4 * t.mesh.indices.len() as u64;
                s.grid_mesh.add(&t.grid_stats);
                s.adaptive_mesh.add(&t.adaptive_stats);
            }
        }
    }

    /// Add one viewpoint from its `tiles.json` (a resumed sample that was not re-tiled).
    pub fn add_tiles_file(&mut self, file: &crate::io::TilesFile) {
        self.samples += 1;
        for l in &file.layers {
            let Some(s) = self.slabs.get_mut(l.slab) else {
                continue;
            };
            s.tiles_before += l.tiles_before;
            s.tiles_after += l.tiles.len();
            for t in &l.tiles {
                s.opaque_pixels += t.opaque_pixels as u64;
                s.pixels += t.pixels as u64;
                s.texture_bytes += 4 * t.pixels as u64;
                s.mesh_bytes += 12 * t.vertex_count as u64 + 4 * t.index_count as u64;
                s.grid_mesh.add(&t.grid_stats);
                s.adaptive_mesh.add(&t.adaptive_stats);
            }
        }
    }

    /// The Markdown report.
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        s.push_str("# Slabs\n\n");
        s.push_str(&format!(
            "{} viewpoint(s), faces of {} px, tiles of {} px, mesh step {} px, adaptive bound {} px (parallax at B = {:.3} m); {:.2} s.\n\n",
            self.samples, self.face_size, self.tile_size, self.mesh_params.step,
            self.mesh_params.max_error_px, self.mesh_params.baseline_m, self.seconds
        ));
        s.push_str(&format!("**Choice:** {}\n\n", self.criterion.summary));
        s.push_str("![depth histogram with the chosen boundaries](histogram.png)\n\n");
        s.push_str("| slab | near (m) | far (m) | tiles before | tiles after | opaque px | tile px | texture bytes | mesh bytes | grid tris / max err px | adaptive tris / max err px |\n");
        s.push_str("|---|---|---|---|---|---|---|---|---|---|---|\n");
        for (k, x) in self.slabs.iter().enumerate() {
            let far = if x.far.is_finite() {
                format!("{:.3}", x.far)
            } else {
                "inf".into()
            };
            s.push_str(&format!(
                "| {k} | {:.3} | {far} | {} | {} | {} | {} | {} | {} | {} / {:.3} | {} / {:.3} |\n",
                x.near,
                x.tiles_before,
                x.tiles_after,
                x.opaque_pixels,
                x.pixels,
                x.texture_bytes,
                x.mesh_bytes,
                x.grid_mesh.triangles,
                x.grid_mesh.max_error_px,
                x.adaptive_mesh.triangles,
                x.adaptive_mesh.max_error_px
            ));
        }
        s.push_str("\n## Candidate boundaries\n\n");
        s.push_str(&format!(
            "B/2 = {:.3} m, θ_pixel = (π/2)/{} = {:.3e} rad, threshold {} px, minimum revealed fraction {:.1e}. Occlusion edges are neighbouring low-res pixels whose gap opens wider than the threshold at B/2 (the parallax (B/2)(1/z_near − 1/z_far)/θ_pixel, compare Meyer & Neyret's h·tan(a)/e ≤ 1); the fewest valleys that separate them are placed, each revealing at least the minimum fraction of the panorama. Parallax (px) below is that of the histogram clusters either side of the candidate.\n\n",
            self.criterion.half_baseline_m, self.criterion.face_size,
            self.criterion.theta_pixel_rad, self.criterion.threshold_px,
            self.criterion.min_edge_fraction
        ));
        if self.criterion.candidates.is_empty() {
            s.push_str("No gap or valley in the histogram.\n");
        } else {
            s.push_str("| kind | depth (m) | near cluster (m) | far cluster (m) | parallax (rad) | parallax (px) | placed | why |\n|---|---|---|---|---|---|---|---|\n");
            for c in &self.criterion.candidates {
                s.push_str(&format!(
                    "| {} | {:.3} | {:.3} | {:.3} | {:.3e} | {:.3} | {} | {} |\n",
                    c.kind,
                    c.depth_m,
                    c.near_cluster_m,
                    c.far_cluster_m,
                    c.parallax_rad,
                    c.parallax_px,
                    if c.accepted { "yes" } else { "no" },
                    c.reason
                ));
            }
        }
        s
    }
}

fn boundary_of(c: &CriterionReport, r: &SlabRange) -> Option<Candidate> {
    if c.manual || r.near <= 0.0 {
        return None;
    }
    c.candidates
        .iter()
        .find(|x| x.accepted && (x.depth_m - r.near).abs() <= 1e-9 * r.near)
        .cloned()
}
