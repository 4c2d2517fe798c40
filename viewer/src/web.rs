//! The browser viewer (`viewer/web/`), compiled into the binary: [`SITE`] is what `railview
//! serve` serves beside a database (`/` is `index.html`) and what [`write_site`] writes beside
//! every database's manifest, so a database folder is a complete website any static host
//! serves. Plain ES modules and WebGL2: nothing is built or fetched from elsewhere at run time.

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
    "main.js",
    "render.js",
    "plan.js",
    "track.js",
    "fetch.js",
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
}
