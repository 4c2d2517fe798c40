//! The sampling bound beside railview's own figures: for every view between two samples, the
//! exact warp ([`bound::exact_warp`]) of the same two reference panoramas with their exact
//! depth, read from the prerender directory, holes left black and holes filled, and the
//! per-pixel oracle of the two. Where railview is far below the filled bound the renderer
//! loses it; where railview is at the bound, only more or better samples help.
//!
//! The position weight of the second reference is linear along the segment. Each view's
//! pixels are classified by the warp ([`bound::PixelClass`]); [`ClassTally`] sums railview's
//! squared error and the filled bound's per class, so a report can say which part of the
//! renderer loses the error (holes, pixels only one reference sees, depth edges, smooth
//! interiors, sky).

use std::path::Path;
use std::sync::Arc;

use bound::{exact_warp, oracle, PixelClass, Reference, WarpOptions};
use prerender::store::{self, PrerenderDir};
use serde::{Deserialize, Serialize};
use tracks::{CubeMap, PerspectiveCamera};

use super::EvalView;
use crate::headless::HeadlessError;
use crate::source::Walkthrough;

/// Config name of the exact warp with holes left black.
pub const EXACT_BLACK: &str = "exact warp, holes black";
/// Config name of the exact warp with holes filled from the farther side.
pub const EXACT_FILLED: &str = "exact warp, filled";
/// Config name of the per-pixel oracle of the two references (unreachable).
pub const ORACLE: &str = "oracle (per-pixel best of two)";

type Panorama = Arc<(CubeMap<[u8; 3]>, CubeMap<f32>)>;

/// The reference panoramas of one prerender directory, the last few kept in memory.
pub struct BoundSource {
    dir: PrerenderDir,
    cache: Vec<(usize, Panorama)>,
}

/// The three bound pictures of one view.
pub struct BoundViews {
    pub black: Vec<[u8; 3]>,
    pub filled: Vec<[u8; 3]>,
    pub oracle: Vec<[u8; 3]>,
    pub class: Vec<PixelClass>,
    /// Pixels that are holes of the warp (filled in `filled`).
    pub hole_fraction: f64,
}

impl BoundSource {
    /// The panoramas of prerender directory `dir` (its `prerender.json` must exist).
    pub fn open(dir: &Path) -> Result<BoundSource, HeadlessError> {
        let dir = PrerenderDir::new(dir);
        dir.read_report()
            .map_err(|e| HeadlessError::Parameter(format!("sampling bound: {e}")))?;
        Ok(BoundSource {
            dir,
            cache: Vec::new(),
        })
    }

    fn panorama(&mut self, index: usize) -> Result<Panorama, HeadlessError> {
        if let Some((_, p)) = self.cache.iter().find(|(i, _)| *i == index) {
            return Ok(p.clone());
        }
        let err = |e: store::StoreError| HeadlessError::Parameter(format!("sampling bound: {e}"));
        let color = store::read_rgb_png(&self.dir.color_png(index)).map_err(err)?;
        let depth = store::read_depth_exr(&self.dir.depth_exr(index)).map_err(err)?;
        let p = Arc::new((color, depth));
        if self.cache.len() >= 4 {
            self.cache.remove(0);
        }
        self.cache.push((index, p.clone()));
        Ok(p)
    }

    /// The bound of `view` (between the two samples of `walk` around it), seen by `camera`,
    /// the oracle judged against `truth`; `None` at a sample or outside the samples.
    pub fn warp(
        &mut self,
        walk: &Walkthrough,
        view: &EvalView,
        camera: &PerspectiveCamera,
        truth: &[[u8; 3]],
    ) -> Result<Option<BoundViews>, HeadlessError> {
        if view.at_reference {
            return Ok(None);
        }
        // The walkthrough's own samples around the view (its spacing may differ from the
        // one the views were placed by).
        let order = walk.order();
        let Some(k) = order.iter().rposition(|&i| walk.views[i].s <= view.s) else {
            return Ok(None);
        };
        let (Some(va), Some(vb)) = (
            order.get(k).and_then(|&i| walk.views.get(i)),
            order.get(k + 1).and_then(|&i| walk.views.get(i)),
        ) else {
            return Ok(None);
        };
        let len = vb.s - va.s;
        if len.is_nan() || len <= 0.0 {
            return Ok(None);
        }
        let t = ((view.s - va.s) / len).clamp(0.0, 1.0);
        let (pa, pb) = (self.panorama(va.index)?, self.panorama(vb.index)?);
        let a = Reference {
            position: va.position,
            color: &pa.0,
            depth: &pa.1,
        };
        let b = Reference {
            position: vb.position,
            color: &pb.0,
            depth: &pb.1,
        };
        let opts = WarpOptions::default();
        let err = |e: bound::BoundError| HeadlessError::Parameter(format!("sampling bound: {e}"));
        let w = exact_warp(&a, &b, t, camera, &opts).map_err(err)?;
        let best = oracle(&a, &b, camera, &opts, truth).map_err(err)?;
        let holes = w.class.iter().filter(|c| **c == PixelClass::Hole).count();
        Ok(Some(BoundViews {
            hole_fraction: holes as f64 / w.class.len().max(1) as f64,
            black: w.black,
            filled: w.filled,
            oracle: best,
            class: w.class,
        }))
    }
}

/// Squared error per pixel class, summed over views: railview's (one configuration) and the
/// filled bound's, with the pixel counts.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ClassTally {
    pub rows: Vec<ClassRow>,
}

/// One pixel class of a [`ClassTally`].
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ClassRow {
    pub class: String,
    pub pixels: u64,
    /// Sum of squared 8-bit channel errors against the truth.
    pub railview_sse: f64,
    pub bound_sse: f64,
}

fn class_name(c: PixelClass) -> &'static str {
    match c {
        PixelClass::Hole => "hole (filled)",
        PixelClass::Sky => "sky",
        PixelClass::OneView => "one reference only",
        PixelClass::DepthEdge => "depth edge",
        PixelClass::Interior => "smooth interior",
    }
}

fn sse(a: [u8; 3], b: [u8; 3]) -> f64 {
    (0..3).map(|k| (a[k] as f64 - b[k] as f64).powi(2)).sum()
}

impl ClassTally {
    /// Add one view: railview's picture, the bound's, the truth, the classes.
    pub fn add(&mut self, railview: &[[u8; 3]], bound: &BoundViews, truth: &[[u8; 3]]) {
        for (i, c) in bound.class.iter().enumerate() {
            let name = class_name(*c);
            let pos = match self.rows.iter().position(|r| r.class == name) {
                Some(p) => p,
                None => {
                    self.rows.push(ClassRow {
                        class: name.into(),
                        ..Default::default()
                    });
                    self.rows.len() - 1
                }
            };
            let (Some(r), Some(b), Some(t)) = (railview.get(i), bound.filled.get(i), truth.get(i))
            else {
                continue;
            };
            let row = &mut self.rows[pos];
            row.pixels += 1;
            row.railview_sse += sse(*r, *t);
            row.bound_sse += sse(*b, *t);
        }
    }

    /// A Markdown table: per class its share of the pixels, of railview's error, and
    /// railview's error over the bound's there.
    pub fn markdown(&self) -> String {
        let pixels: u64 = self.rows.iter().map(|r| r.pixels).sum();
        let total: f64 = self.rows.iter().map(|r| r.railview_sse).sum();
        let mut m = String::from(
            "| pixel class (from the exact warp) | pixels % | railview's error % | railview ÷ bound (squared error) |\n|---|---|---|---|\n",
        );
        for r in &self.rows {
            m += &format!(
                "| {} | {:.2} | {:.1} | {} |\n",
                r.class,
                100.0 * r.pixels as f64 / pixels.max(1) as f64,
                100.0 * r.railview_sse / total.max(f64::MIN_POSITIVE),
                if r.bound_sse > 0.0 {
                    format!("{:.2}", r.railview_sse / r.bound_sse)
                } else {
                    "–".into()
                }
            );
        }
        m
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn class_tally_sums_errors_per_class() {
        let bound = BoundViews {
            black: vec![[0; 3]; 3],
            filled: vec![[10, 10, 10], [0, 0, 0], [5, 5, 5]],
            oracle: vec![[0; 3]; 3],
            class: vec![PixelClass::Hole, PixelClass::Interior, PixelClass::Interior],
            hole_fraction: 1.0 / 3.0,
        };
        let truth = vec![[0u8; 3]; 3];
        let railview = vec![[20, 20, 20], [1, 1, 1], [0, 0, 0]];
        let mut t = ClassTally::default();
        t.add(&railview, &bound, &truth);
        let hole = t.rows.iter().find(|r| r.class == "hole (filled)").unwrap();
        assert_eq!(
            (hole.pixels, hole.railview_sse, hole.bound_sse),
            (1, 1200.0, 300.0)
        );
        let interior = t
            .rows
            .iter()
            .find(|r| r.class == "smooth interior")
            .unwrap();
        assert_eq!(interior.pixels, 2);
        assert_eq!((interior.railview_sse, interior.bound_sse), (3.0, 75.0));
        let md = t.markdown();
        assert!(
            md.contains("| hole (filled) | 33.33 | 99.8 | 4.00 |"),
            "{md}"
        );
    }
}
