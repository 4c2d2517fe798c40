//! How a sweep makes each configuration's database from stages that other configurations
//! share.
//!
//! A configuration is a chain of [`Node`]s, each one stage run once in a directory of its own
//! (`ROOT/nodes/NAME/`), named by a digest of everything that decides its output:
//!
//! | stage | decided by | runs |
//! |---|---|---|
//! | [`Stage::Prerender`] | scene, track sampling, face size, supersampling | `stages::prerender` (tracer or POV-Ray) |
//! | [`Stage::Layers`] | + slab choice | `stages::slabs`, layers only |
//! | [`Stage::Tiles`] | + tile size, mesh error | `stages::slabs` |
//! | [`Stage::Cull`] | + culling variant and α | `stages::cull` (none without culling) |
//! | [`Stage::Database`] | + finest levels left out, zstd level, ACH | `stages::build` |
//!
//! A node starts as hard links to its parent's files (every stage writes whole files under
//! new names, so the parent's stay as they were) and runs its stage, which finds the
//! parent's outputs and adds its own. Configurations that agree on the early knobs share the
//! early nodes; a node that exists is never run again.

mod nodes;

use std::path::PathBuf;

use serde::{Deserialize, Serialize};
use stages::build::{BuildParams, BuildScene};
use stages::cull::CullParams;
use stages::prerender::PrerenderParams;
use stages::slabs::SlabsParams;

pub use nodes::nodes;

/// What every configuration of a sweep shares.
#[derive(Clone, Debug, PartialEq)]
pub struct Setup {
    /// The scene, and who renders it (POV-Ray: its up axis only; the rest as POV-Ray's
    /// defaults).
    pub scene: BuildScene,
    /// The sweep's directory.
    pub root: PathBuf,
    pub lowres_face_size: Option<u32>,
    pub zstd_level: i32,
    pub ach_samples: usize,
    pub ach_camera_size: u32,
}

/// The stages of [`Node`]s, in order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Stage {
    Prerender,
    Layers,
    Tiles,
    Cull,
    Database,
}

impl Stage {
    /// Whether its CPU time counts as prerendering (rendering panoramas and layers) rather
    /// than building.
    pub fn is_prerender(self) -> bool {
        matches!(self, Stage::Prerender | Stage::Layers)
    }
}

/// What a node runs: one stage function and its parameters.
#[derive(Clone, Debug, PartialEq)]
pub enum StageParams {
    Prerender(PrerenderParams),
    /// The layers (`layers_only`) or the tiles.
    Slabs(SlabsParams),
    Cull(CullParams),
    Build(Box<BuildParams>),
}

/// One stage of one or more configurations.
#[derive(Clone, Debug, PartialEq)]
pub struct Node {
    pub stage: Stage,
    /// Everything that decides the output, as text.
    pub key: String,
    /// `ROOT/nodes/NAME`.
    pub dir: PathBuf,
    /// The node whose files this one starts from.
    pub parent: Option<PathBuf>,
    pub params: StageParams,
}

impl Node {
    /// The `railview` command line (after `railview`) that runs the same stage, for
    /// records and messages; never parsed.
    pub fn command_line(&self) -> Vec<String> {
        match &self.params {
            StageParams::Prerender(p) => p.command_line(),
            StageParams::Slabs(p) if p.layers_only => p.command_line(),
            StageParams::Slabs(p) => vec![
                "slabs".into(),
                p.dir.display().to_string(),
                "--slabs".into(),
                p.slabs.to_string(),
                "--tile-size".into(),
                p.tiling.tile_size.to_string(),
                "--mesh-error".into(),
                p.tiling.mesh_error_px.to_string(),
            ],
            StageParams::Cull(p) => p.command_line(),
            StageParams::Build(p) => nodes::build_command(p),
        }
    }
}

/// FNV-1a, 64 bits: short stable names for keys (not a security hash).
pub fn digest(text: &str) -> u64 {
    text.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    })
}
