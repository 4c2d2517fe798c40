//! The browser viewer (`viewer/web/`), compiled into the binary: [`SITE`] is what `railview
//! serve` serves beside a database (`/` is `index.html`) and what [`write_site`] writes beside
//! every database's manifest, so a database folder is a complete website any static host
//! serves. Plain ES modules and WebGL2: nothing is built or fetched from elsewhere at run time.
//!
//! The page runs under [`streamer::server::CONTENT_SECURITY_POLICY`]: no inline script or
//! style, no markup made from strings, and nothing loaded from another origin.

use std::path::Path;

use streamer::server::SiteFile;

macro_rules! site {
    ($($name:literal),* $(,)?) => {
        &[$(SiteFile { name: $name, body: include_str!(concat!("../web/", $name)) }),*]
    };
}

/// Every file of the browser viewer.
pub const SITE: &[SiteFile] = site!(
    "index.html",
    "viewer.css",
    "favicon.svg",
    "main.js",
    "render.js",
    "plan.js",
    "track.js",
    "pieces.js",
    "limits.js",
    "fetch.js",
    "pool.js",
    "worker.js",
    "table.js",
    "ptm.js",
    "mesh.js",
    "entropy.js",
    "blake3.js",
);

/// Writes the browser viewer into `dir` (beside `manifest.json`), each file whole, rewriting
/// only files that changed.
pub fn write_site(dir: &Path) -> std::io::Result<()> {
    for f in SITE {
        railview_files::write_if_changed(&dir.join(f.name), f.body.as_bytes())?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn site_text(name: &str) -> &'static str {
        SITE.iter()
            .find(|f| f.name == name)
            .unwrap_or_else(|| panic!("{name} is not in the site"))
            .body
    }

    #[test]
    fn every_module_the_page_imports_is_in_the_site() {
        for f in SITE {
            for line in f.body.lines() {
                let Some(rest) = line.split(" from \"./").nth(1) else {
                    continue;
                };
                let name = rest.split('"').next().unwrap();
                assert!(
                    SITE.iter().any(|g| g.name == name),
                    "{} imports {name}, which the site lacks",
                    f.name
                );
            }
        }
        assert!(SITE.iter().any(|f| f.name == "index.html"));
    }

    #[test]
    fn every_file_the_page_links_is_in_the_site_and_served_with_its_type() {
        let page = site_text("index.html");
        let mut linked = 0;
        for attr in [" href=\"", " src=\""] {
            for rest in page.split(attr).skip(1) {
                let name = rest.split('"').next().unwrap();
                assert!(
                    SITE.iter().any(|g| g.name == name),
                    "index.html links {name}, which the site lacks"
                );
                linked += 1;
            }
        }
        assert!(linked >= 3, "the page links its style, icon and script");
        for f in SITE {
            assert_ne!(
                f.content_type(),
                "application/octet-stream",
                "{} would be served without a type browsers accept under nosniff",
                f.name
            );
        }
    }

    /// What a `style-src 'self'; script-src 'self'` policy refuses, or what would let a
    /// string from a database reach the page as markup.
    #[test]
    fn the_page_has_no_inline_script_or_style_and_makes_no_markup_from_strings() {
        let page = site_text("index.html");
        assert!(!page.contains("<style"), "index.html has an inline <style>");
        assert!(
            !page.contains(" style="),
            "index.html has a style attribute"
        );
        for tag in page.split("<script").skip(1) {
            let open = &tag[..tag.find('>').unwrap()];
            assert!(open.contains(" src="), "index.html has an inline script");
        }
        assert!(
            !page.split_whitespace().any(|w| w.starts_with("on")
                && w.contains('=')
                && w[..w.find('=').unwrap()]
                    .chars()
                    .all(|c| c.is_ascii_lowercase())),
            "index.html has an event-handler attribute"
        );
        let refused = [
            "innerHTML",
            "outerHTML",
            "insertAdjacentHTML",
            "document.write",
            "setAttribute(\"style\"",
            "setAttribute('style'",
            ".style =",
            "cssText",
            "eval(",
            "new Function",
            "blob:",
            "createObjectURL",
        ];
        for f in SITE.iter().filter(|f| f.name.ends_with(".js")) {
            for (n, line) in f.body.lines().enumerate() {
                for r in refused {
                    assert!(!line.contains(r), "{}:{}: {r}", f.name, n + 1);
                }
            }
        }
    }

    /// The number a JavaScript constant expression of the site stands for: a literal
    /// (`8192`, `1e7`, `100_000`), `A << B` or `A ** B`.
    fn js_number(expr: &str) -> f64 {
        let literal = |s: &str| -> f64 {
            s.trim()
                .replace('_', "")
                .parse()
                .unwrap_or_else(|_| panic!("`{expr}` is not a constant this test reads"))
        };
        if let Some((a, b)) = expr.split_once("<<") {
            let v = literal(a) * 2f64.powf(literal(b));
            // JavaScript shifts 32-bit integers: 1 << 31 is negative.
            assert!(v < 2f64.powi(31), "`{expr}` overflows a JavaScript shift");
            v
        } else if let Some((a, b)) = expr.split_once("**") {
            literal(a).powf(literal(b))
        } else {
            literal(expr)
        }
    }

    /// The value of `const NAME = …;` or of an object's `NAME: …` in the site file `file`.
    fn js_constant(file: &str, name: &str) -> f64 {
        let body = site_text(file);
        let start = [format!("const {name} = "), format!(" {name}: ")]
            .iter()
            .find_map(|p| body.find(p.as_str()).map(|i| i + p.len()))
            .unwrap_or_else(|| panic!("{file} defines no {name}"));
        let rest = &body[start..];
        let end = rest.find([';', ',', '}', '\n']).unwrap();
        js_number(&rest[..end])
    }

    /// The browser checks what a database sends against the same limits as the Rust
    /// readers: each JavaScript limit is read from its file and compared with Rust's.
    #[test]
    fn the_browser_limits_are_the_rust_limits() {
        use tracks::limits as l;
        let ptm = codec::ptm::Limits::default();
        let tracks_limits: &[(&str, f64)] = &[
            ("MAX_FACE_SIZE", l::MAX_FACE_SIZE as f64),
            ("MIN_TILE_SIZE", l::MIN_TILE_SIZE as f64),
            ("MAX_TILES_PER_SIDE", l::MAX_TILES_PER_SIDE as f64),
            ("MAX_VIEWPOINTS", l::MAX_VIEWPOINTS as f64),
            ("MAX_TRACK_POINTS", l::MAX_TRACK_POINTS as f64),
            ("MAX_TRACKS", l::MAX_TRACKS as f64),
            ("MAX_SLABS", l::MAX_SLABS as f64),
            ("MAX_TEXT_BYTES", l::MAX_TEXT_BYTES as f64),
            ("MAX_GRID_CELLS", l::MAX_GRID_CELLS as f64),
            ("MAX_MANIFEST_BYTES", l::MAX_MANIFEST_BYTES as f64),
            ("MAX_COORDINATE_M", l::MAX_COORDINATE_M),
            ("MAX_TABLE_BYTES", db::table::MAX_TABLE_BYTES as f64),
        ];
        let codecs: &[(&str, &str, f64)] = &[
            ("mesh.js", "MAX_SIDE", codec::mesh::MAX_SIDE as f64),
            ("mesh.js", "MAX_CELLS", codec::mesh::MAX_CELLS as f64),
            ("mesh.js", "MAX_BOX_SIDE", codec::mesh::MAX_BOX_SIDE as f64),
            ("mesh.js", "MAX_WORK", codec::mesh::MAX_WORK as f64),
            ("ptm.js", "maxSide", ptm.max_side as f64),
            ("ptm.js", "maxDecodedBytes", ptm.max_decoded_bytes as f64),
            ("ptm.js", "MAX_NEAR", codec::ptm::MAX_NEAR as f64),
            (
                "pieces.js",
                "MAX_PIECE_BYTES",
                db::index::MAX_PIECE_BYTES as f64,
            ),
            ("pieces.js", "MAX_LEVELS", db::index::MAX_LEVELS as f64),
            (
                "table.js",
                "MAX_OTHER_PACKS",
                db::table::MAX_OTHER_PACKS as f64,
            ),
        ];
        let pairs = tracks_limits.iter().map(|&(n, v)| ("limits.js", n, v));
        for (file, name, rust) in pairs.chain(codecs.iter().copied()) {
            assert_eq!(
                js_constant(file, name),
                rust,
                "{file}'s {name} differs from Rust's"
            );
        }
        // Every limit of limits.js has its Rust counterpart above, and no other module
        // defines one of its own, under its name or another (a byte size spelt as a shift,
        // such as a table object's `64 << 20`, is written nowhere else).
        for line in site_text("limits.js").lines() {
            if let Some(rest) = line.strip_prefix("export const ") {
                let name = rest.split(' ').next().unwrap();
                let value = rest.split_once(" = ").unwrap().1.trim_end_matches(';');
                assert!(
                    tracks_limits.iter().any(|&(n, _)| n == name),
                    "limits.js's {name} is compared with no Rust limit"
                );
                for f in SITE.iter().filter(|f| f.name != "limits.js") {
                    assert!(
                        !f.body.contains(&format!("const {name} =")),
                        "{} defines {name} again instead of importing it from limits.js",
                        f.name
                    );
                    assert!(
                        !(value.contains("<<") && f.body.contains(value)),
                        "{} spells {name}'s value `{value}` instead of importing it from \
                         limits.js",
                        f.name
                    );
                }
            }
        }
    }
}
