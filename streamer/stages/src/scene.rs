//! Scenes and tracks as the stages name them: a built-in scene or a scene TOML file (with the
//! files it names, each within [`MAX_ASSET_BYTES`]), and a track of the scene or a track file.

use std::path::Path;

use prerender::scene::Scene;
use tracks::{Track, TrackSet};

use crate::error::{input, parameter, Context, Error, Result};

/// Largest file a scene names (an OBJ mesh, an image texture) or a scene or track file,
/// bytes.
pub const MAX_ASSET_BYTES: u64 = 256 << 20;

/// A file's bytes, refused unread when larger than [`MAX_ASSET_BYTES`]; the message does not
/// name the file (callers do).
fn read_capped(path: &Path) -> std::result::Result<Vec<u8>, String> {
    use std::io::Read;
    let f = std::fs::File::open(path).map_err(|e| e.to_string())?;
    let len = f.metadata().map_err(|e| e.to_string())?.len();
    if len > MAX_ASSET_BYTES {
        return Err(format!(
            "{len} bytes; files of at most {MAX_ASSET_BYTES} bytes are read"
        ));
    }
    let mut out = Vec::with_capacity(len as usize);
    f.take(MAX_ASSET_BYTES)
        .read_to_end(&mut out)
        .map_err(|e| e.to_string())?;
    Ok(out)
}

/// A file a scene names, within [`MAX_ASSET_BYTES`] (the message names the file).
pub fn read_asset(path: &Path) -> std::result::Result<Vec<u8>, String> {
    read_capped(path).map_err(|e| format!("{}: {e}", path.display()))
}

/// A scene or track file as text, within [`MAX_ASSET_BYTES`].
pub fn read_text(path: &Path) -> Result<String> {
    let bytes = read_capped(path).map_err(Error::Input)?;
    String::from_utf8(bytes).map_err(|e| input!("not UTF-8 text: {e}"))
}

/// A scene TOML file with the files it names, relative to its folder.
fn parse_scene_file(path: &Path, name: &str, context: &str) -> Result<(Scene, String)> {
    let text = read_text(path).with_context(|| format!("{context} {}", path.display()))?;
    let base = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let loader =
        move |rel: &str| -> std::result::Result<Vec<u8>, String> { read_asset(&base.join(rel)) };
    let scene = Scene::parse_toml_with(&text, name, &loader)?;
    Ok((scene, text))
}

/// The scene `spec` names (a built-in scene or a scene TOML file) and its tracks, if it has
/// any.
pub fn load_scene(spec: &str) -> Result<(Scene, Option<TrackSet>)> {
    if let Some(b) = prerender::scenes::builtin(spec) {
        return Ok((b.scene, Some(b.tracks)));
    }
    let path = Path::new(spec);
    if !path.exists() {
        if let Some(e) = prerender::scenes::name_error(spec) {
            return Err(parameter!("{e}"));
        }
        return Err(parameter!(
            "scene `{spec}` is neither a built-in scene ({}) nor an existing file",
            prerender::scenes::names_help()
        ));
    }
    let (scene, text) = parse_scene_file(path, spec, "reading scene file")?;
    let tracks = prerender::parse::tracks_from_scene_toml(&text, spec)?;
    Ok((scene, tracks))
}

/// The exact geometry of a built-in scene or a scene TOML file (for culling against solids
/// and the oracle); `context` says what reads it.
pub fn load_geometry(spec: &str, context: &str) -> Result<Scene> {
    if let Some(b) = prerender::scenes::builtin(spec) {
        return Ok(b.scene);
    }
    let path = Path::new(spec);
    Ok(parse_scene_file(path, spec, &format!("{context}: reading scene file"))?.0)
}

/// The track `spec` names: a track of the scene, or a track file (its only track, or its
/// track `main`).
pub fn pick_track(spec: &str, scene_tracks: Option<&TrackSet>) -> Result<Track> {
    if let Some(t) = scene_tracks.and_then(|s| s.get(spec)) {
        return Ok(t.clone());
    }
    let path = Path::new(spec);
    if !path.is_file() {
        let names = scene_tracks.map_or(String::from("none"), |s| s.names().join(", "));
        return Err(parameter!(
            "track `{spec}` is neither a track of the scene (tracks: {names}) nor a track file"
        ));
    }
    let text = read_text(path).with_context(|| format!("reading track file {}", path.display()))?;
    let set = TrackSet::parse(&text, spec)?;
    match set.tracks.as_slice() {
        [one] => Ok(one.clone()),
        _ => match set.get("main") {
            Some(t) => Ok(t.clone()),
            None => Err(parameter!(
                "{spec}: holds several tracks ({}) and none is named `main`",
                set.names().join(", ")
            )),
        },
    }
}

/// The tracks `spec` (and `name`) choose: `all` (or `name` `all`) for every track of the
/// scene or file, else one track as [`pick_track`] finds it; the name for the report
/// (`all` for a network).
pub fn pick_tracks(
    spec: &str,
    name: Option<&str>,
    scene_tracks: Option<&TrackSet>,
) -> Result<(String, Vec<Track>)> {
    use crate::network::{choose_tracks, ALL_TRACKS};
    if spec == ALL_TRACKS && !Path::new(spec).is_file() {
        let set = scene_tracks.ok_or_else(|| parameter!("--track all: the scene has no tracks"))?;
        return choose_tracks(set, Some(ALL_TRACKS), "the scene", false);
    }
    if name.is_some() && Path::new(spec).is_file() {
        let text =
            read_text(Path::new(spec)).with_context(|| format!("reading track file {spec}"))?;
        let set = TrackSet::parse(&text, spec)?;
        return choose_tracks(&set, name, spec, false);
    }
    let t = pick_track(spec, scene_tracks)?;
    Ok((t.name.clone(), vec![t]))
}

/// The track `track` names: a track file (its track `track_name`, `main` or its only one),
/// or a track of the scene (built-in or scene file).
pub fn resolve_track(scene: Option<&str>, track: &str, track_name: Option<&str>) -> Result<Track> {
    let from_file = |path: &Path| -> Result<TrackSet> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("reading track file {}", path.display()))?;
        Ok(TrackSet::parse(&text, &path.display().to_string())?)
    };
    let set = if Path::new(track).is_file() {
        from_file(Path::new(track))?
    } else if let Some(b) = scene.and_then(prerender::scenes::builtin) {
        b.tracks
    } else if let Some(scene) = scene.filter(|s| Path::new(s).is_file()) {
        let text = std::fs::read_to_string(scene)
            .with_context(|| format!("reading scene file {scene}"))?;
        prerender::parse::tracks_from_scene_toml(&text, scene)?
            .ok_or_else(|| input!("{scene} has no [[track]]"))?
    } else {
        return Err(parameter!(
            "track `{track}` is neither a track file nor a track of the scene"
        ));
    };
    let name = track_name.unwrap_or(track);
    match set.get(name) {
        Some(t) => Ok(t.clone()),
        None if set.tracks.len() == 1 => Ok(set.tracks[0].clone()),
        None => set.get("main").cloned().ok_or_else(|| {
            parameter!(
                "no track `{name}` or `main` among {}",
                set.names().join(", ")
            )
        }),
    }
}
