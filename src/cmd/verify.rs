//! `railview verify DB`: checks every file of a database (with `--decode`, every PTM's and
//! mesh's content too); exit status 0 only when intact.

use std::path::PathBuf;

use anyhow::Context;

#[derive(clap::Args)]
pub struct Args {
    /// Database directory (the one holding manifest.json and objects/).
    pub db: PathBuf,
    /// Print the report as JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Also decode every PTM to its finest level and every mesh, and check that every PTM
    /// texel with alpha 0 holds colour 0 (what readers dividing coarse levels by their alpha
    /// rely on). Reads and decodes everything: slower.
    #[arg(long)]
    pub decode: bool,
    /// Remove the stray temporary files an interrupted write left (names with a leading
    /// `.` and a `.tmp` marker in the database's directory, objects/ or objects/HH/).
    #[arg(long)]
    pub remove_temp: bool,
    /// First write this railview's browser viewer beside the database (`index.html` and its
    /// modules, as `railview build` does), replacing changed or older copies.
    #[arg(long)]
    pub rewrite_site: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if args.rewrite_site {
        viewer::web::write_site(&args.db)
            .with_context(|| format!("writing the browser viewer into {}", args.db.display()))?;
    }
    let site: Vec<(&str, &[u8])> = viewer::web::SITE
        .iter()
        .map(|f| (f.name, f.body.as_bytes()))
        .collect();
    let opts = db::VerifyOptions {
        decode: args.decode,
        remove_temp: args.remove_temp,
        site: &site,
    };
    let report = db::verify_with(&args.db, opts)
        .with_context(|| format!("verifying {}", args.db.display()))?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "{}: {} objects referenced, {} files ({} bytes) hashed, {} viewpoint tables decoded, {} PTM level ranges checked",
            args.db.display(),
            report.objects_referenced,
            report.files_checked,
            report.bytes_checked,
            report.tables_checked,
            report.level_ranges_checked
        );
        println!(
            "{} of the browser viewer's {} files beside it as this railview writes them",
            report.site_files_checked,
            site.len()
        );
        if args.decode {
            println!(
                "{} PTMs and {} meshes decoded",
                report.ptms_decoded, report.meshes_decoded
            );
        }
        for n in &report.notes {
            println!("note: {}: {}", n.path.display(), n.what);
        }
        for s in &report.stray {
            let done = if report.removed.contains(&s.path) {
                "removed"
            } else {
                "`--remove-temp` removes it"
            };
            println!("stray: {}: {} ({done})", s.path.display(), s.what);
        }
        for p in &report.problems {
            println!("DAMAGED: {}: {}", p.path.display(), p.what);
        }
    }
    if report.is_intact() {
        let left = report.stray.len() - report.removed.len();
        if !args.json {
            match (left, report.removed.len()) {
                (0, 0) => println!("intact"),
                (0, n) => println!("intact ({n} stray temporary file(s) removed)"),
                (n, _) => println!(
                    "intact, but {n} stray temporary file(s) are not part of the database \
                     (`railview verify --remove-temp` removes them)"
                ),
            }
        }
        Ok(())
    } else {
        anyhow::bail!(
            "{} problem(s) in {}; first: {}: {}",
            report.problems.len(),
            args.db.display(),
            report.problems[0].path.display(),
            report.problems[0].what
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exit_status_follows_damage_and_names_the_file() {
        let dir = std::env::temp_dir().join(format!("railview-verify-cmd-{}", std::process::id()));
        std::fs::remove_dir_all(&dir).ok();
        let mut w = db::DbWriter::create(&dir).unwrap();
        let obj = w.put(b"some object bytes").unwrap();
        let manifest = tracks::manifest::Manifest {
            version: tracks::manifest::MANIFEST_VERSION,
            scene: "t".into(),
            face_size: 16,
            tile_size: 16,
            slabs: vec![],
            cull_alpha: None,
            cull_variant: None,
            tracks: vec![tracks::manifest::TrackEntry {
                name: "main".into(),
                track_toml:
                    "[[track]]\nname = \"main\"\npoints = [[0, 0, 0], [1, 0, 0]]\ncount = 1\n"
                        .into(),
                length: 1.0,
                viewpoints: vec![tracks::manifest::ViewpointEntry {
                    index: 0,
                    s: 0.0,
                    position: Default::default(),
                    background: Vec::new(),
                    tiles: vec![tracks::manifest::TileEntry {
                        tile: tracks::TileId {
                            face: tracks::Face::PosX,
                            tx: 0,
                            ty: 0,
                        },
                        slab: 0,
                        depth_min: 1.0,
                        depth_max: 2.0,
                        opaque_pixels: 1,
                        kept: true,
                        ptm: None,
                        mesh: Some(obj.clone()),
                        mesh_range: None,
                    }],
                }],
                segments: vec![],
            }],
        };
        w.finish(&manifest).unwrap();
        let args = || Args {
            db: dir.clone(),
            json: false,
            decode: true,
            remove_temp: false,
            rewrite_site: false,
        };
        run(args()).unwrap();
        let path = dir.join(obj.rel_path().unwrap());
        let mut bytes = std::fs::read(&path).unwrap();
        bytes[3] ^= 1;
        std::fs::write(&path, &bytes).unwrap();
        let err = format!("{:#}", run(args()).unwrap_err());
        assert!(err.contains(&path.display().to_string()), "{err}");
        bytes[3] ^= 1;
        std::fs::write(&path, &bytes).unwrap();
        run(args()).unwrap();
        // A missing viewpoint table is named by viewpoint.
        let top = db::read_top(&dir).unwrap();
        let table = dir.join(top.viewpoints[0].table.rel_path().unwrap());
        std::fs::remove_file(&table).unwrap();
        let err = format!("{:#}", run(args()).unwrap_err());
        assert!(
            err.contains("table of viewpoint 0") && err.contains("missing"),
            "{err}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
