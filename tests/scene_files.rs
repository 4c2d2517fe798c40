//! Every scene file and POV-Ray track file shipped in `scenes/` reads without error, with
//! the tracks its header comment's build command names (a file that rots is found here, not
//! by a user).

use std::path::Path;

fn files(dir: &str) -> Vec<std::path::PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join(dir);
    let mut out: Vec<_> = std::fs::read_dir(&root)
        .unwrap_or_else(|e| panic!("{}: {e}", root.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    out.sort();
    out
}

#[test]
fn every_scene_file_parses_and_has_a_main_track() {
    let scenes = files("scenes");
    assert!(scenes.len() >= 4, "{scenes:?}");
    for path in scenes {
        let spec = path.to_str().unwrap();
        let scene = prerender::truth::load_scene(spec).unwrap_or_else(|e| panic!("{spec}: {e}"));
        assert!(!scene.desc().objects.is_empty(), "{spec}: no objects");
        let text = std::fs::read_to_string(&path).unwrap();
        let set = prerender::parse::tracks_from_scene_toml(&text, spec)
            .unwrap_or_else(|e| panic!("{spec}: {e}"))
            .unwrap_or_else(|| panic!("{spec}: no [[track]]"));
        assert!(
            set.tracks.iter().any(|t| t.name == "main"),
            "{spec}: no track `main`"
        );
    }
}

#[test]
fn every_pov_track_file_parses() {
    let tracks = files("scenes/pov");
    assert!(tracks.len() >= 4, "{tracks:?}");
    for path in tracks {
        let text = std::fs::read_to_string(&path).unwrap();
        let set = tracks::TrackSet::parse(&text, path.to_str().unwrap())
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert!(!set.tracks.is_empty(), "{}", path.display());
        // Every file is a network whatever `--track-name` picks: no near misses.
        let net = tracks::network::Network::new(set.tracks.clone())
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        if path.ends_with("patio-network.toml") {
            assert_eq!(net.tracks.len(), 3, "{}", path.display());
            assert_eq!(net.junctions.len(), 2, "{}", path.display());
        }
        for t in &set.tracks {
            assert!(
                t.viewpoints().len() >= 2,
                "{}: track {}",
                path.display(),
                t.name
            );
        }
    }
}
