//! The chain of nodes of one configuration.

use std::path::{Path, PathBuf};

use db::ach::AchParams;
use stages::build::{BuildParams, BuildScene};
use stages::cull::{CullParams, Variants};
use stages::encode::EncodeParams;
use stages::prerender::{PovParams, PrerenderParams, Renderer};
use stages::slabs::{SlabsParams, Tiling};
use stages::Knobs;

use super::{digest, Node, Setup, Stage, StageParams};

/// The keys of a configuration's stages, each extending the one before.
struct Keys {
    pre: String,
    layers: String,
    tiles: String,
    cull: String,
    db: String,
}

impl Keys {
    fn new(setup: &Setup, knobs: &Knobs, track_text: &str) -> Keys {
        let scene_key = match &setup.scene {
            BuildScene::Tracer(scene) => format!("tracer:{scene}"),
            BuildScene::PovRay { scene, pov } => format!(
                "pov:{} up {:?}",
                scene.display(),
                pov.up.map(|u| u.name().to_string())
            ),
        };
        let pre = format!(
            "{scene_key} | track {:016x} | face {} | ss {} | lowres {:?}",
            digest(track_text),
            knobs.face_size,
            knobs.supersample,
            setup.lowres_face_size
        );
        let layers = format!("{pre} | slabs {}", knobs.slabs);
        let tiles = format!(
            "{layers} | tile {} | mesh {}",
            knobs.tile_size, knobs.mesh_error_px
        );
        let cull = format!("{tiles} | cull {} {}", knobs.cull, knobs.alpha);
        let db = format!(
            "{cull} | drop {} | zstd {} | ach {} {}",
            knobs.drop_levels, setup.zstd_level, setup.ach_samples, setup.ach_camera_size
        );
        Keys {
            pre,
            layers,
            tiles,
            cull,
            db,
        }
    }
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
    let keys = Keys::new(setup, knobs, track_text);
    let d_pre = node_dir(
        &format!("pre-f{}-ss{}", knobs.face_size, knobs.supersample),
        &keys.pre,
    );
    let d_layers = node_dir("layers", &keys.layers);
    let d_tiles = node_dir("tiles", &keys.tiles);
    let d_cull = node_dir("cull", &keys.cull);
    let d_db = node_dir("db", &keys.db);
    let pre_dir = |d: &Path| d.join("prerender");
    let slabs = |d: &Path, layers_only: bool| SlabsParams {
        slabs: knobs.slabs.clone(),
        tiling: Tiling {
            tile_size: knobs.tile_size,
            mesh_error_px: knobs.mesh_error_px,
            ..Tiling::default()
        },
        layers_only,
        ..SlabsParams::new(pre_dir(d))
    };
    let mut out = vec![
        Node {
            stage: Stage::Prerender,
            key: keys.pre,
            dir: d_pre.clone(),
            parent: None,
            params: StageParams::Prerender(prerender(setup, knobs, track_file, &pre_dir(&d_pre))),
        },
        Node {
            stage: Stage::Layers,
            key: keys.layers,
            dir: d_layers.clone(),
            parent: Some(d_pre),
            params: StageParams::Slabs(slabs(&d_layers, true)),
        },
        Node {
            stage: Stage::Tiles,
            key: keys.tiles,
            dir: d_tiles.clone(),
            parent: Some(d_layers),
            params: StageParams::Slabs(slabs(&d_tiles, false)),
        },
    ];
    let pov = matches!(setup.scene, BuildScene::PovRay { .. });
    let last = match knobs.cull.resolve(pov, knobs.alpha) {
        None => d_tiles,
        Some(variant) => {
            out.push(Node {
                stage: Stage::Cull,
                key: keys.cull,
                dir: d_cull.clone(),
                parent: Some(d_tiles),
                params: StageParams::Cull(CullParams {
                    dir: pre_dir(&d_cull),
                    alphas: vec![knobs.alpha],
                    variants: Variants::These(vec![variant]),
                    oracle: None,
                    renders_per_segment: None,
                }),
            });
            d_cull
        }
    };
    out.push(Node {
        stage: Stage::Database,
        key: keys.db,
        dir: d_db.clone(),
        parent: Some(last),
        params: StageParams::Build(Box::new(build(setup, knobs, track_file, &d_db))),
    });
    out
}

/// The first stage: the tracer, or POV-Ray (anti-aliased at 2×2 supersampling).
fn prerender(setup: &Setup, knobs: &Knobs, track_file: &Path, out: &Path) -> PrerenderParams {
    let (scene, renderer) = match &setup.scene {
        BuildScene::Tracer(scene) => (
            scene.clone(),
            Renderer::Builtin {
                supersample: knobs.supersample,
                shadows: true,
            },
        ),
        BuildScene::PovRay { scene, pov } => (
            scene.display().to_string(),
            Renderer::PovRay(PovParams {
                up: pov.up,
                supersample: knobs.supersample,
                ..PovParams::default()
            }),
        ),
    };
    PrerenderParams {
        scene,
        track: track_file.display().to_string(),
        track_name: None,
        face_size: knobs.face_size,
        lowres_face_size: setup.lowres_face_size,
        out: out.to_path_buf(),
        slabs: None,
        shard: None,
        merge: false,
        renderer,
    }
}

/// The last stage: the whole build, which finds every earlier stage's outputs in its work
/// directory. A POV-Ray build asks for anti-aliasing rather than supersampling.
fn build(setup: &Setup, knobs: &Knobs, track_file: &Path, dir: &Path) -> BuildParams {
    let (scene, supersample) = match &setup.scene {
        BuildScene::Tracer(s) => (BuildScene::Tracer(s.clone()), knobs.supersample),
        BuildScene::PovRay { scene, pov } => (
            BuildScene::PovRay {
                scene: scene.clone(),
                pov: PovParams {
                    up: pov.up,
                    supersample: knobs.supersample,
                    ..PovParams::default()
                },
            },
            1,
        ),
    };
    BuildParams {
        work: Some(dir.to_path_buf()),
        lowres_face_size: setup.lowres_face_size,
        knobs: Knobs {
            every: 1,
            samples: None,
            spacing_m: None,
            supersample,
            zstd_level: setup.zstd_level,
            ..knobs.clone()
        },
        encode: EncodeParams {
            zstd_level: setup.zstd_level,
            drop_levels: knobs.drop_levels,
            ach: AchParams {
                samples: setup.ach_samples,
                camera_size: setup.ach_camera_size,
            },
            ..EncodeParams::default()
        },
        ..BuildParams::new(scene, &track_file.display().to_string(), &dir.join("db"))
    }
}

/// The command line of a database node, as the sweep has always recorded it.
pub(super) fn build_command(p: &BuildParams) -> Vec<String> {
    let k = &p.knobs;
    let mut v: Vec<String> = match &p.scene {
        BuildScene::Tracer(scene) => vec![
            "build".into(),
            "--scene".into(),
            scene.clone(),
            "--supersample".into(),
            k.supersample.to_string(),
        ],
        BuildScene::PovRay { scene, pov } => {
            let mut v = vec!["build".into(), "--pov".into(), scene.display().to_string()];
            if let Some(up) = pov.up {
                v.extend(["--up".into(), up.name().into()]);
            }
            if pov.supersample > 1 {
                v.extend(["--supersample".into(), pov.supersample.to_string()]);
            }
            v
        }
    };
    let path = |d: &Option<PathBuf>| {
        d.as_ref()
            .map_or(String::new(), |d| d.display().to_string())
    };
    v.extend([
        "--track".into(),
        p.track.clone(),
        "--face-size".into(),
        k.face_size.to_string(),
        "--slabs".into(),
        k.slabs.to_string(),
        "--tile-size".into(),
        k.tile_size.to_string(),
        "--mesh-error".into(),
        k.mesh_error_px.to_string(),
        "--cull-variant".into(),
        k.cull.to_string(),
        "--alpha".into(),
        k.alpha.to_string(),
        "--drop-levels".into(),
        k.drop_levels.to_string(),
        "--zstd-level".into(),
        k.zstd_level.to_string(),
        "--ach-samples".into(),
        p.encode.ach.samples.to_string(),
        "--ach-camera-size".into(),
        p.encode.ach.camera_size.to_string(),
        "--out".into(),
        p.out.display().to_string(),
        "--work".into(),
        path(&p.work),
    ]);
    if let Some(n) = p.lowres_face_size {
        v.extend(["--lowres-face-size".into(), n.to_string()]);
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;
    use stages::CullChoice;

    fn setup() -> Setup {
        Setup {
            scene: BuildScene::Tracer("castle".into()),
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
            .command_line()
            .windows(2)
            .any(|w| w == ["--cull-variant", "none"]));
        // Another sampling of the track is another prerender.
        let d = nodes(&setup(), &Knobs::default(), t, "other track");
        assert_ne!(a[0].dir, d[0].dir);
    }

    #[test]
    fn command_lines_are_those_the_sweep_recorded() {
        let t = Path::new("/sweep/track.toml");
        let n = nodes(&setup(), &Knobs::default(), t, "track");
        let text: Vec<String> = n.iter().map(|n| n.command_line().join(" ")).collect();
        let d = |i: usize| n[i].dir.display().to_string();
        assert_eq!(
            text[0],
            format!(
                "prerender --scene castle --track /sweep/track.toml --supersample 1 --face-size 128 --out {}/prerender",
                d(0)
            )
        );
        assert_eq!(
            text[1],
            format!("slabs {}/prerender --slabs auto --layers-only", d(1))
        );
        assert_eq!(
            text[2],
            format!(
                "slabs {}/prerender --slabs auto --tile-size 32 --mesh-error 0.5",
                d(2)
            )
        );
        assert_eq!(
            text[3],
            format!("cull {}/prerender --alpha 1 --variant conservative", d(3))
        );
        assert_eq!(
            text[4],
            format!(
                "build --scene castle --supersample 1 --track /sweep/track.toml --face-size 128 \
                 --slabs auto --tile-size 32 --mesh-error 0.5 --cull-variant conservative \
                 --alpha 1 --drop-levels 0 --zstd-level 19 --ach-samples 8 --ach-camera-size 64 \
                 --out {0}/db --work {0}",
                d(4)
            )
        );
    }
}
