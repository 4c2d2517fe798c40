//! The pictures of an evaluation: its worst views between samples, and its worst view at a
//! reference sample (what limits the floor), each beside its truth and their difference.

use std::path::Path;

use super::{camera, draw, triptych, worst_views, EvalRow, Truth, TruthCache};
use crate::gpu::Renderer;
use crate::headless::HeadlessError;
use crate::plan::DrawBudget;
use crate::source::Walkthrough;

/// What the pictures are drawn with.
pub struct PictureInput<'a> {
    pub renderer: &'a mut Renderer,
    /// The rows' walkthrough; a row on another track of a network moves it there.
    pub walk: &'a mut Walkthrough,
    /// The configuration pictured and its budget.
    pub config: &'a str,
    pub budget: DrawBudget,
    pub size: (u32, u32),
    pub fov_deg: f64,
    pub cache: &'a TruthCache,
    pub truth: &'a mut Truth,
}

/// Write `worst-1.png` … `worst-N.png` (the `n` worst rows of the configuration between
/// samples) and `worst-at-sample.png` into `out`; returns the worst rows, worst first.
pub fn worst_pictures(
    input: PictureInput<'_>,
    rows: &[EvalRow],
    n: usize,
    out: &Path,
) -> Result<Vec<EvalRow>, HeadlessError> {
    let worst: Vec<EvalRow> = worst_views(rows, input.config, n)
        .into_iter()
        .cloned()
        .collect();
    input.renderer.forget_views();
    let at_sample = rows
        .iter()
        .filter(|r| r.config == input.config && r.view.at_reference)
        .min_by(|a, b| a.psnr_db.total_cmp(&b.psnr_db));
    let named = worst
        .iter()
        .enumerate()
        .map(|(i, w)| (format!("worst-{}.png", i + 1), w))
        .chain(at_sample.map(|w| ("worst-at-sample.png".to_string(), w)));
    let err = |e: String| HeadlessError::Parameter(format!("eval pictures: {e}"));
    for (file, w) in named {
        if w.view.track != input.walk.current {
            input.walk.set_track(w.view.track);
        }
        let cam = camera(input.walk, &w.view, input.size, input.fov_deg);
        let gt = input.cache.get(&input.walk.scene, &cam, input.truth)?;
        let rgba = draw(input.renderer, input.walk, &cam, w.view.s, input.budget)?;
        let (rgb, _) = crate::metrics::split_rgba(&rgba);
        let img = triptych(&rgb, &gt, input.size.0, input.size.1);
        let mut bytes = std::io::Cursor::new(Vec::new());
        img.write_to(&mut bytes, image::ImageFormat::Png)
            .map_err(|e| err(e.to_string()))?;
        prerender::store::write_atomic(&out.join(file), bytes.get_ref())
            .map_err(|e| err(e.to_string()))?;
    }
    Ok(worst)
}
