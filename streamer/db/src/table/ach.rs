//! The ACH object: the ACH lists of the segments starting at a viewpoint (the layout is in
//! the [module docs](super)), fetched only by clients that rank tiles by ACH.

use tracks::manifest::{AchEntry, SegmentEntry};

use super::decode::{open_body, Dec};
use super::encode::{framed, put_varint};
use super::{tile_index, TableError};

/// First bytes of every ACH object.
pub const ACH_MAGIC: &[u8; 4] = b"RVAC";
/// ACH object format written and read by this crate.
pub const ACH_VERSION: u8 = 1;

/// The bytes of the ACH object of viewpoint `viewpoint`: the ACH lists of the segments that
/// start there (see the module docs).
pub fn encode_ach(viewpoint: usize, segments: &[SegmentEntry]) -> Result<Vec<u8>, TableError> {
    let n = segments
        .iter()
        .flat_map(|s| s.ach.iter().map(|a| a.tile))
        .map(|t| t.tx.max(t.ty) as u64 + 1)
        .max()
        .unwrap_or(0);
    let mut b = Vec::with_capacity(16 + segments.iter().map(|s| s.ach.len() * 6).sum::<usize>());
    put_varint(&mut b, viewpoint as u64);
    put_varint(&mut b, n);
    put_varint(&mut b, segments.len() as u64);
    for s in segments {
        put_varint(&mut b, s.to as u64);
        put_varint(&mut b, s.ach.len() as u64);
        for a in &s.ach {
            let i = tile_index(n, a.slab, a.tile)
                .and_then(|i| i.checked_mul(4))
                .ok_or_else(|| {
                    TableError::Layout(format!(
                        "ACH entry {:?} {} {} of slab {} cannot be numbered",
                        a.tile.face, a.tile.tx, a.tile.ty, a.slab
                    ))
                })?;
            if a.viewpoint == viewpoint {
                put_varint(&mut b, i);
            } else if a.viewpoint == s.to {
                put_varint(&mut b, i + 1);
            } else {
                put_varint(&mut b, i + 2);
                put_varint(&mut b, a.viewpoint as u64);
            }
        }
        for a in &s.ach {
            b.extend_from_slice(&(a.ach as f32).to_le_bytes());
        }
    }
    Ok(framed(ACH_MAGIC, ACH_VERSION, b))
}

/// Decodes an ACH object's bytes (already checked against its hash) for viewpoint `want`.
pub fn decode_ach(bytes: &[u8], want: usize) -> Result<Vec<SegmentEntry>, TableError> {
    let mut unzipped = Vec::new();
    let mut r = open_body(bytes, ACH_MAGIC, ACH_VERSION, want, &mut unzipped)?;
    let viewpoint = want;
    let d = Dec {
        n: r.varint("grid side")?,
        hash_bytes: 4,
        pack: None,
        others: Vec::new(),
        cursor: 0,
    };
    let ns = r.count("segment count", 2)?;
    let mut segments = Vec::with_capacity(ns);
    for _ in 0..ns {
        let to = r.usize("segment end")?;
        // Each entry takes at least a one-byte code and an f32.
        let ne = r.count("ACH entry count", 5)?;
        let mut ach = Vec::with_capacity(ne);
        for _ in 0..ne {
            let at = r.at;
            let code = r.varint("ACH tile")?;
            let vp = match code % 4 {
                0 => viewpoint,
                1 => to,
                2 => r.usize("ACH viewpoint")?,
                w => return Err(r.invalid("ACH tile", at, format!("owner code {w} (0–2)"))),
            };
            let (slab, tile) = d.position(&r, at, code / 4, "ACH tile")?;
            ach.push(AchEntry {
                viewpoint: vp,
                slab,
                tile,
                ach: 0.0,
            });
        }
        for a in &mut ach {
            a.ach = r.f32("ACH value")? as f64;
        }
        segments.push(SegmentEntry {
            from: viewpoint,
            to,
            ach,
        });
    }
    if r.at != r.b.len() {
        return Err(TableError::Trailing(r.b.len() - r.at));
    }
    Ok(segments)
}
