//! How a sweep makes each configuration's database from stages that other configurations
//! share.
//!
//! A configuration is a chain of [`Node`]s, each one stage run once in a directory of its own
//! (`ROOT/nodes/NAME/`), named by a digest of everything that decides its output:
//!
//! | stage | decided by | runs |
//! |---|---|---|
//! | [`Stage::Prerender`] | scene, track sampling, face size, supersampling | `prerender` / `import-pov` |
//! | [`Stage::Layers`] | + slab choice | `slabs --layers-only` |
//! | [`Stage::Tiles`] | + tile size, mesh error | `slabs` |
//! | [`Stage::Cull`] | + culling variant and α | `cull` (none for `none`) |
//! | [`Stage::Database`] | + finest levels left out, zstd level, ACH | `build` |
//!
//! A node starts as hard links to its parent's files (every stage writes whole files under
//! new names, so the parent's stay as they were) and runs its command, which finds the
//! parent's outputs and adds its own. Configurations that agree on the early knobs share the
//! early nodes; a node that exists is never run again.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::knobs::{CullChoice, Knobs};

/// The scene of a sweep.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum SceneSpec {
    /// A built-in scene name or a TOML scene file: the built-in tracer.
    Tracer { scene: String },
    /// A POV-Ray scene and its up axis (`y`, `z`): POV-Ray.
    Pov { scene: String, up: Option<String> },
}

impl SceneSpec {
    pub fn name(&self) -> &str {
        match self {
            SceneSpec::Tracer { scene } | SceneSpec::Pov { scene, .. } => scene,
        }
    }
}

/// What every configuration of a sweep shares.
#[derive(Clone, Debug, PartialEq)]
pub struct Setup {
    pub scene: SceneSpec,
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
    /// The `railview` command line (after `railview`).
    pub argv: Vec<String>,
}

/// FNV-1a, 64 bits: short stable names for keys (not a security hash).
pub fn digest(text: &str) -> u64 {
    text.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    })
}

fn p(path: &Path) -> String {
    path.display().to_string()
}

/// The nodes that make the database of `knobs`, first to last; the last one's directory
/// holds it (`db/`) and its build report. `track_file` holds the track sampled as `knobs`
/// asks (one track).
pub fn nodes(setup: &Setup, knobs: &Knobs, track_file: &Path, track_text: &str) -> Vec<Node> {
    let node_dir = |prefix: &str, key: &str| {
        setup
            .root
            .join("nodes")
            .join(format!("{prefix}-{:016x}", digest(key)))
    };
    let scene_key = match &setup.scene {
        SceneSpec::Tracer { scene } => format!("tracer:{scene}"),
        SceneSpec::Pov { scene, up } => format!("pov:{scene} up {up:?}"),
    };
    let lowres = setup.lowres_face_size;
    let k_pre = format!(
        "{scene_key} | track {:016x} | face {} | ss {} | lowres {lowres:?}",
        digest(track_text),
        knobs.face_size,
        knobs.supersample
    );
    let d_pre = node_dir(
        &format!("pre-f{}-ss{}", knobs.face_size, knobs.supersample),
        &k_pre,
    );
    let mut pre_argv = match &setup.scene {
        SceneSpec::Tracer { scene } => vec![
            "prerender".into(),
            "--scene".into(),
            scene.clone(),
            "--track".into(),
            p(track_file),
            "--supersample".into(),
            knobs.supersample.to_string(),
        ],
        SceneSpec::Pov { scene, up } => {
            let mut v = vec![
                "import-pov".into(),
                scene.clone(),
                "--track".into(),
                p(track_file),
            ];
            if let Some(up) = up {
                v.extend(["--up".into(), up.clone()]);
            }
            if knobs.supersample == 2 {
                v.push("--aa".into());
            }
            v
        }
    };
    pre_argv.extend([
        "--face-size".into(),
        knobs.face_size.to_string(),
        "--out".into(),
        p(&d_pre.join("prerender")),
    ]);
    if let Some(n) = lowres {
        pre_argv.extend(["--lowres-face-size".into(), n.to_string()]);
    }
    let pre_dir = |d: &Path| p(&d.join("prerender"));
    let k_layers = format!("{k_pre} | slabs {}", knobs.slabs);
    let d_layers = node_dir("layers", &k_layers);
    let k_tiles = format!(
        "{k_layers} | tile {} | mesh {}",
        knobs.tile_size, knobs.mesh_error_px
    );
    let d_tiles = node_dir("tiles", &k_tiles);
    let k_cull = format!("{k_tiles} | cull {} {}", knobs.cull, knobs.alpha);
    let d_cull = node_dir("cull", &k_cull);
    let k_db = format!(
        "{k_cull} | drop {} | zstd {} | ach {} {}",
        knobs.drop_levels, setup.zstd_level, setup.ach_samples, setup.ach_camera_size
    );
    let d_db = node_dir("db", &k_db);
    let mut out = vec![
        Node {
            stage: Stage::Prerender,
            key: k_pre,
            dir: d_pre.clone(),
            parent: None,
            argv: pre_argv,
        },
        Node {
            stage: Stage::Layers,
            key: k_layers,
            dir: d_layers.clone(),
            parent: Some(d_pre),
            argv: vec![
                "slabs".into(),
                pre_dir(&d_layers),
                "--slabs".into(),
                knobs.slabs.to_string(),
                "--layers-only".into(),
            ],
        },
        Node {
            stage: Stage::Tiles,
            key: k_tiles,
            dir: d_tiles.clone(),
            parent: Some(d_layers),
            argv: vec![
                "slabs".into(),
                pre_dir(&d_tiles),
                "--slabs".into(),
                knobs.slabs.to_string(),
                "--tile-size".into(),
                knobs.tile_size.to_string(),
                "--mesh-error".into(),
                knobs.mesh_error_px.to_string(),
            ],
        },
    ];
    let last = if knobs.cull == CullChoice::Off {
        d_tiles
    } else {
        out.push(Node {
            stage: Stage::Cull,
            key: k_cull,
            dir: d_cull.clone(),
            parent: Some(d_tiles),
            argv: vec![
                "cull".into(),
                pre_dir(&d_cull),
                "--alpha".into(),
                knobs.alpha.to_string(),
                "--variant".into(),
                knobs.cull.to_string(),
            ],
        });
        d_cull
    };
    let mut build = match &setup.scene {
        SceneSpec::Tracer { scene } => vec![
            "build".into(),
            "--scene".into(),
            scene.clone(),
            "--supersample".into(),
            knobs.supersample.to_string(),
        ],
        SceneSpec::Pov { scene, up } => {
            let mut v = vec!["build".into(), "--pov".into(), scene.clone()];
            if let Some(up) = up {
                v.extend(["--up".into(), up.clone()]);
            }
            if knobs.supersample == 2 {
                v.push("--aa".into());
            }
            v
        }
    };
    build.extend([
        "--track".into(),
        p(track_file),
        "--face-size".into(),
        knobs.face_size.to_string(),
        "--slabs".into(),
        knobs.slabs.to_string(),
        "--tile-size".into(),
        knobs.tile_size.to_string(),
        "--mesh-error".into(),
        knobs.mesh_error_px.to_string(),
        "--cull-variant".into(),
        knobs.cull.to_string(),
        "--alpha".into(),
        knobs.alpha.to_string(),
        "--drop-levels".into(),
        knobs.drop_levels.to_string(),
        "--zstd-level".into(),
        setup.zstd_level.to_string(),
        "--ach-samples".into(),
        setup.ach_samples.to_string(),
        "--ach-camera-size".into(),
        setup.ach_camera_size.to_string(),
        "--out".into(),
        p(&d_db.join("db")),
        "--work".into(),
        p(&d_db),
    ]);
    if let Some(n) = lowres {
        build.extend(["--lowres-face-size".into(), n.to_string()]);
    }
    out.push(Node {
        stage: Stage::Database,
        key: k_db,
        dir: d_db,
        parent: Some(last),
        argv: build,
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn setup() -> Setup {
        Setup {
            scene: SceneSpec::Tracer {
                scene: "castle".into(),
            },
            root: PathBuf::from("/sweep"),
            lowres_face_size: None,
            zstd_level: 19,
            ach_samples: 8,
            ach_camera_size: 64,
        }
    }

    #[test]
    fn configurations_share_the_stages_they_agree_on() {
        let base = Knobs::default();
        let tiles16 = Knobs {
            tile_size: 16,
            ..base.clone()
        };
        let t = Path::new("/sweep/track.toml");
        let a = nodes(&setup(), &base, t, "track");
        let b = nodes(&setup(), &tiles16, t, "track");
        assert_eq!(a.len(), 5);
        assert_eq!((a[0].dir == b[0].dir, a[1].dir == b[1].dir), (true, true));
        assert!(a[2].dir != b[2].dir && a[4].dir != b[4].dir);
        // Each node starts from its parent.
        for w in a.windows(2) {
            assert_eq!(w[1].parent.as_ref(), Some(&w[0].dir));
        }
        // Without culling the database starts from the tiles.
        let none = Knobs {
            cull: CullChoice::Off,
            ..base
        };
        let c = nodes(&setup(), &none, t, "track");
        assert_eq!(c.len(), 4);
        assert_eq!(c[3].parent.as_ref(), Some(&c[2].dir));
        assert!(c[3]
            .argv
            .windows(2)
            .any(|w| w == ["--cull-variant", "none"]));
        // Another sampling of the track is another prerender.
        let d = nodes(&setup(), &Knobs::default(), t, "other track");
        assert_ne!(a[0].dir, d[0].dir);
    }
}
