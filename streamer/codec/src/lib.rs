//! codec: the byte formats of railview's payloads, as pure functions over bytes — no file
//! system, no network, no async. Each module documents its format byte for byte, precisely
//! enough to write a second decoder in another language.
//!
//! - [`entropy`]: the adaptive binary range coder under both codecs ([`entropy::Encoder`],
//!   the sans-IO [`entropy::Decoder`], adaptive [`entropy::Bit`]s and the integer
//!   binarisations [`entropy::Unsigned`] and [`entropy::Signed`]).
//! - [`ptm`]: progressive texture maps (format 3) — lossless (or near-lossless) mip levels
//!   sent coarse to fine, level group by level group ([`ptm::encode`], the streaming
//!   [`ptm::Decoder`] bounded by [`ptm::Limits`]).
//! - [`mesh`]: compact tile meshes (format 4) — lattice occupancy, connectivity grown edge by
//!   edge and inverse planar depth quantised to a bound in pixels of parallax
//!   ([`mesh::encode_mesh`], [`mesh::decode_mesh`]).
//!
//! ```
//! use codec::mesh::{decode_mesh, encode_mesh, MeshCoding, TileMesh};
//! use codec::ptm::{decode, encode, EncodeOptions, Image, Limits};
//!
//! let img = Image::from_fn(8, 8, 4, |x, y, c| (x * 30 + y * 5 + c as u32) as u8);
//! let enc = encode(&img, &EncodeOptions::default()).unwrap();
//! assert_eq!(decode(&enc.bytes, Limits::default()).unwrap(), img);
//!
//! let mesh = TileMesh {
//!     vertices: vec![[0.5, 0.5, 10.0], [4.5, 0.5, 10.0], [0.5, 4.5, 10.0]],
//!     indices: vec![0, 1, 2],
//! };
//! let bytes = encode_mesh(&mesh, &MeshCoding::for_parallax(64, 1.0, 0.25)).unwrap();
//! let back = decode_mesh(&bytes).unwrap();
//! assert_eq!(back.indices, mesh.indices);
//! ```

pub mod entropy;
pub mod mesh;
pub mod ptm;
