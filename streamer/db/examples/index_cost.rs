//! What a database's index costs a client: the root's bytes, every piece (nodes and chunks,
//! their number and bytes, the largest chunk) and what a client that reads only the pieces
//! on the way to one cell needs before its first view there (the root, a node per level, the
//! chunk).
//!
//! ```text
//! cargo run --release -p db --example index_cost -- DB [X Z]
//! cargo run --release -p db --example index_cost -- DB --cells 16,32,64,128,256
//! ```
//!
//! `X Z` (metres) is the place of the first view; by default the first track's first
//! viewpoint. Prints one JSON object. With `--cells`, the database's graph is cut again into
//! chunks of each size (in memory, nothing written) and one line per size gives the pieces,
//! their bytes, the largest chunk, and the index a first view at the first viewpoint needs.

use std::path::PathBuf;

use db::index::{decode_chunk, decode_node};
use tracks::manifest::ObjectRef;

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dir = PathBuf::from(
        args.first()
            .ok_or("usage: index_cost DB [X Z | --cells A,B,…]")?,
    );
    let (root, raw) = db::read_root(&dir).map_err(|e| e.to_string())?;
    let (top, refs) = db::read_index(&dir, root.clone()).map_err(|e| e.to_string())?;
    if args.get(1).map(String::as_str) == Some("--cells") {
        let sizes = args
            .get(2)
            .ok_or("--cells: sizes in metres, comma separated")?;
        for cell in sizes.split(',') {
            let cell: f64 = cell
                .trim()
                .parse()
                .map_err(|e| format!("--cells {cell}: {e}"))?;
            println!("{}", recut(&top, cell)?);
        }
        return Ok(());
    }
    let at = match (args.get(1), args.get(2)) {
        (Some(x), Some(z)) => (
            x.parse::<f64>().map_err(|e| format!("X: {e}"))?,
            z.parse::<f64>().map_err(|e| format!("Z: {e}"))?,
        ),
        _ => {
            let first = top.tracks.first().and_then(|t| t.stops.first());
            let p = first.map(|s| top.viewpoints[s.viewpoint].position);
            p.map(|p| (p.x, p.z))
                .ok_or("the database has no viewpoint")?
        }
    };
    let cell = root
        .index
        .cell_of(at.0, at.1)
        .ok_or_else(|| format!("({}, {}) lies outside the index", at.0, at.1))?;
    // The path from the root to that cell's chunk.
    let read = |r: &ObjectRef| db::read_piece(&dir, r).map_err(|e| e.to_string());
    let (path_bytes, chunk) = path_to(&root, cell, read)?;
    let chunk_viewpoints = chunk.map_or(0, |c| c.viewpoints.len());
    let mut chunks = Vec::new();
    for r in &refs {
        let bytes = read(r)?;
        let json =
            db::gunzip_limited(&bytes, db::index::MAX_PIECE_BYTES).map_err(|e| e.to_string())?;
        if json.starts_with(b"{\"x\"") {
            chunks.push(bytes.len() as u64);
        }
    }
    let out = serde_json::json!({
        "database": dir.display().to_string(),
        "viewpoints": top.viewpoints.len(),
        "tracks": top.tracks.len(),
        "junctions": top.junctions.len(),
        "cell_m": root.index.cell,
        "levels": root.index.levels,
        "root_bytes": raw.len(),
        "pieces": refs.len(),
        "piece_bytes": refs.iter().map(|r| r.size).sum::<u64>(),
        "chunks": chunks.len(),
        "largest_chunk_bytes": chunks.iter().max(),
        "mean_chunk_bytes": chunks.iter().sum::<u64>() / chunks.len().max(1) as u64,
        "first_view_at": [at.0, at.1],
        "first_view_cell": [cell.0, cell.1],
        "first_view_chunk_viewpoints": chunk_viewpoints,
        "first_view_index_bytes": raw.len() as u64 + path_bytes,
    });
    println!("{out:#}");
    Ok(())
}

/// The graph cut into chunks of `cell` metres: pieces, bytes, the largest chunk, and the
/// index a first view at the first track's first viewpoint needs (root, path, chunk).
fn recut(top: &db::TopManifest, cell: f64) -> Result<serde_json::Value, String> {
    let (root, pieces) = db::index::pieces(top, cell)?;
    let store: std::collections::HashMap<String, &Vec<u8>> =
        pieces.iter().map(|b| (db::hash_hex(b), b)).collect();
    let p = top
        .tracks
        .first()
        .and_then(|t| t.stops.first())
        .map(|s| top.viewpoints[s.viewpoint].position)
        .ok_or("the database has no viewpoint")?;
    let target = root
        .index
        .cell_of(p.x, p.z)
        .ok_or("the first viewpoint is outside")?;
    let root_bytes = serde_json::to_vec(&root).map_err(|e| e.to_string())?.len() as u64 + 1;
    let fetch = |r: &ObjectRef| Ok::<_, String>(store[&r.hash].clone());
    let (path, _) = path_to(&root, target, fetch)?;
    let chunks: Vec<u64> = pieces
        .iter()
        .filter(|b| {
            db::gunzip_limited(b, db::index::MAX_PIECE_BYTES)
                .is_ok_and(|j| j.starts_with(b"{\"x\""))
        })
        .map(|b| b.len() as u64)
        .collect();
    Ok(serde_json::json!({
        "cell_m": cell,
        "levels": root.index.levels,
        "pieces": pieces.len(),
        "piece_bytes": pieces.iter().map(|b| b.len() as u64).sum::<u64>(),
        "chunks": chunks.len(),
        "largest_chunk_bytes": chunks.iter().max(),
        "root_bytes": root_bytes,
        "first_view_index_bytes": root_bytes + path,
    }))
}

/// The bytes of the pieces from the root to cell `cell`'s chunk (a node a level, then the
/// chunk), and that chunk when the cell has one.
fn path_to(
    root: &db::index::RootManifest,
    cell: (u64, u64),
    mut fetch: impl FnMut(&ObjectRef) -> Result<Vec<u8>, String>,
) -> Result<(u64, Option<db::index::Chunk>), String> {
    let mut bytes_read = 0u64;
    let mut next = root.index.root_piece();
    while let Some((at, r)) = next.take() {
        let bytes = fetch(&r)?;
        bytes_read += bytes.len() as u64;
        if at.level == 0 {
            return Ok((bytes_read, Some(decode_chunk(&bytes, &at, root)?)));
        }
        let node = decode_node(&bytes, &at)?;
        let shift = at.level - 1;
        next = node
            .children_at()
            .find(|(a, _)| (a.x, a.z) == (cell.0 >> shift, cell.1 >> shift))
            .map(|(a, c)| (a, c.clone()));
    }
    Ok((bytes_read, None))
}
