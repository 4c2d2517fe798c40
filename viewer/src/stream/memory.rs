//! Decoded memory of a streamed walkthrough: views laid out lazily, held within
//! [`StreamedWalkthrough::decoded_budget_bytes`] by dropping the farthest back to
//! placeholders, and laid out coarser when the budget asks for it (see the parent module's
//! docs).

use std::collections::{BTreeSet, HashMap};

use codec::ptm::Decoder;
use tracks::{CubeMap, TileGrid};

use super::items::{item_bytes, mesh_bytes};
use super::StreamedWalkthrough;
use crate::texture::Layer;

impl StreamedWalkthrough {
    /// Hold the decoded views within `bytes` (decoded layers, dense maps, meshes and the
    /// renderer's copy of the layers): the views are laid out at the finest resolution at
    /// which the views that must be held — the pair drawn and the predicted next pair, four
    /// views — fit, and the session fetches no finer PTM level. The same rule for every
    /// database, so memory follows the budget, not the database: a face-512 database laid out
    /// in 96 MiB is drawn from its level 1 (faces of 256), one at face 192 at full
    /// resolution. Views already laid out start over. Returns the layout level.
    pub fn set_memory_budget(&mut self, bytes: u64) -> u32 {
        let (n, t) = (self.db_grid.face_size, self.db_grid.tile_size);
        let max_k = t.max(1).ilog2().min(n.trailing_zeros());
        let k = (0..=max_k)
            .find(|&k| 4 * full_view_bytes(n >> k, self.layer_count) <= bytes)
            .unwrap_or(max_k);
        self.decoded_budget_bytes = bytes;
        if k != self.layout_level {
            for v in 0..self.walk.views.len() {
                self.evict(v);
                self.fresh.insert(v);
            }
            self.layout_level = k;
            self.grid = TileGrid::new(n >> k, t >> k).unwrap_or(self.db_grid);
            for v in &mut self.walk.views {
                v.face_size = self.grid.face_size;
                v.tile_size = self.grid.tile_size;
            }
            self.session.set_finest_level((k > 0).then_some(k));
        }
        k
    }

    /// Whether view `v` (position in `walk.views`) has its full-size layers and dense maps.
    pub(super) fn laid_out(&self, v: usize) -> bool {
        self.dense.get(v).is_some_and(|d| !d.is_empty())
    }

    /// Give view `v` its full-size (transparent) layers and dense maps, when it has none.
    pub(super) fn lay_out(&mut self, v: usize) {
        if self.laid_out(v) {
            return;
        }
        let n = self.walk.views[v].face_size;
        self.dense[v] = vec![CubeMap::filled(n, [0u8; 4]); self.layer_count];
        self.walk.views[v].layers = vec![empty_layer(n); self.layer_count];
        self.fresh.insert(v);
    }

    /// Drop the decoded state of the views farthest along the track from `s` (never those
    /// in `protected`) until the total is within the budget (`per_view`: the decoded bytes
    /// of each view); returns the views dropped.
    pub(super) fn evict_over_budget(
        &mut self,
        s: f64,
        protected: &BTreeSet<usize>,
        per_view: &[u64],
    ) -> Vec<usize> {
        let mut total: u64 = per_view.iter().sum();
        let mut out = Vec::new();
        if total <= self.decoded_budget_bytes {
            return out;
        }
        let mut order: Vec<usize> = (0..per_view.len())
            .filter(|v| !protected.contains(v) && per_view[*v] > 0)
            .collect();
        let dist = |v: usize| (self.walk.views[v].s - s).abs();
        order.sort_by(|&a, &b| dist(b).total_cmp(&dist(a)).then(b.cmp(&a)));
        for v in order {
            if total <= self.decoded_budget_bytes {
                break;
            }
            self.evict(v);
            total = total.saturating_sub(per_view[v]);
            out.push(v);
        }
        out
    }

    /// Back to nothing decoded for view `v`: placeholder layers, no tiles, its items start
    /// over (their parts are consumed again from the session's cache or downloaded again).
    pub(super) fn evict(&mut self, v: usize) {
        let view = &mut self.walk.views[v];
        view.layers = placeholder_layers(self.layer_count);
        view.tiles = Vec::new();
        self.tile_items[v] = Vec::new();
        self.dense[v] = Vec::new();
        self.fresh.remove(&v);
        for &i in &self.view_items[v] {
            let it = &mut self.items[i];
            it.waiting = HashMap::new();
            it.next = 0;
            it.decoder = Decoder::new(it.limits);
            it.mesh = None;
            it.level = None;
            it.loaded_at = None;
        }
    }

    /// Decoded bytes held for view `v`: its layers (all mip levels; counted twice, for the
    /// renderer's copy) and dense maps when laid out, its tiles' meshes, and its items'
    /// decoders, meshes and parts waiting.
    pub fn view_decoded_bytes(&self, v: usize) -> u64 {
        let Some(view) = self.walk.views.get(v) else {
            return 0;
        };
        let maps = if self.laid_out(v) {
            let layers: u64 = view
                .layers
                .iter()
                .flat_map(|l| &l.levels)
                .map(map_bytes)
                .sum();
            // The layers twice: here and in the renderer's textures (which a software
            // rasteriser keeps in main memory too).
            2 * layers + self.dense[v].iter().map(map_bytes).sum::<u64>()
        } else {
            0
        };
        let tiles: u64 = view.tiles.iter().map(|t| mesh_bytes(&t.mesh)).sum();
        let items: u64 = self.view_items[v]
            .iter()
            .map(|&i| item_bytes(&self.items[i]))
            .sum();
        maps + tiles + items
    }

    /// Decoded bytes held over all views (see [`StreamedWalkthrough::view_decoded_bytes`]).
    pub fn decoded_bytes(&self) -> u64 {
        (0..self.walk.views.len())
            .map(|v| self.view_decoded_bytes(v))
            .sum()
    }

    /// Bytes of one laid-out view's layers (with mips, here and in the renderer) and dense
    /// maps: what a view costs once anything of it arrived (decoders and meshes come on top).
    pub fn full_view_bytes(&self) -> u64 {
        full_view_bytes(self.grid.face_size, self.layer_count)
    }

    /// Positions in `walk.views` of the views laid out (holding decoded layers).
    pub fn laid_out_views(&self) -> Vec<usize> {
        (0..self.walk.views.len())
            .filter(|&v| self.laid_out(v))
            .collect()
    }
}

/// Transparent layers with 1×1 faces for a view not laid out: they draw as nothing (no
/// tiles reference them) at a few bytes each.
pub(super) fn placeholder_layers(count: usize) -> Vec<Layer> {
    vec![Layer::from_rgba(CubeMap::filled(1, [0u8; 4])); count]
}

/// A transparent layer of face size `n` with its mip chain, as [`Layer::from_rgba`] of a
/// transparent map builds it, without the downsampling passes.
fn empty_layer(n: u32) -> Layer {
    let mut levels = vec![CubeMap::filled(n, [0u8; 4])];
    let mut m = n;
    while m >= 2 && m.is_multiple_of(2) {
        m /= 2;
        levels.push(CubeMap::filled(m, [0u8; 4]));
    }
    Layer { levels }
}

/// Bytes of one laid-out view of face size `n` with `layers` layers: each layer's mip chain
/// (twice: decoded here and uploaded to the renderer) and its dense level-0 map.
pub(super) fn full_view_bytes(n: u32, layers: usize) -> u64 {
    // 6 faces × 4 bytes per texel, halving as `Layer::from_rgba` does.
    let face = |m: u32| 24 * u64::from(m).pow(2);
    let mut layer = face(n);
    let mut m = n;
    while m >= 2 && m.is_multiple_of(2) {
        m /= 2;
        layer += face(m);
    }
    let dense = face(n);
    layers as u64 * (2 * layer + dense)
}

fn map_bytes(m: &CubeMap<[u8; 4]>) -> u64 {
    std::mem::size_of_val(m.as_slice()) as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_layers_match_the_mip_chain_of_a_transparent_map() {
        for n in [1, 2, 6, 16, 24] {
            let built = Layer::from_rgba(CubeMap::filled(n, [0u8; 4]));
            assert_eq!(empty_layer(n), built, "face {n}");
            let bytes: u64 =
                2 * built.levels.iter().map(map_bytes).sum::<u64>() + map_bytes(&built.levels[0]);
            assert_eq!(full_view_bytes(n, 3), 3 * bytes, "face {n}");
        }
    }

    #[test]
    fn placeholder_layers_are_tiny_and_transparent() {
        let layers = placeholder_layers(3);
        assert_eq!(layers.len(), 3);
        for l in &layers {
            assert_eq!(l.levels.len(), 1);
            assert_eq!(l.face_size(), 1);
            assert!(l.levels[0].as_slice().iter().all(|p| *p == [0u8; 4]));
        }
    }

    #[test]
    fn a_face_1024_view_with_two_slabs() {
        // Layer with mips 33.5 MB (here and in the renderer), dense map 25.2 MB, three layers.
        let b = full_view_bytes(1024, 3);
        assert_eq!(b, 3 * (2 * 33_554_424 + 25_165_824));
    }
}
