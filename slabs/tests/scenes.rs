//! The automatic slab count on the built-in scenes: the occluded `castle` needs more slabs
//! than the open `nature`, and the report says why.

use prerender::render::render_depth_lowres;
use prerender::scenes::builtin;
use slabs::boundaries::{choose, ChooseParams, SlabChoice};

/// Low-res depth at every viewpoint of track `main`, then the automatic choice for faces of
/// `face_size` pixels.
fn auto_choice(name: &str, lowres: u32, face_size: u32) -> SlabChoice {
    let b = builtin(name).expect("built-in scene");
    let track = b.tracks.get("main").expect("track main");
    let vps = track.viewpoints();
    let depths: Vec<_> = vps
        .iter()
        .map(|v| render_depth_lowres(&b.scene, v.position, lowres))
        .collect();
    let spacing = vps
        .windows(2)
        .map(|w| w[0].position.distance(w[1].position))
        .fold(0.0, f64::max);
    choose(&depths, spacing, face_size, &ChooseParams::default())
}

#[test]
fn castle_needs_more_slabs_than_nature() {
    // Low-res faces of 64 (the prerender default), layers of 256.
    let castle = auto_choice("castle", 64, 256);
    let nature = auto_choice("nature", 64, 256);
    for (name, c) in [("castle", &castle), ("nature", &nature)] {
        eprintln!("{name}: {}", c.criterion.summary);
        for x in &c.criterion.candidates {
            eprintln!("  {:.2} m placed {}: {}", x.depth_m, x.accepted, x.reason);
        }
    }
    assert!(
        castle.slabs.len() > nature.slabs.len(),
        "castle {} slabs, nature {}",
        castle.slabs.len(),
        nature.slabs.len()
    );
    // The reasons are in the report: every placed boundary passed the pixel test.
    for c in castle.criterion.candidates.iter().filter(|c| c.accepted) {
        assert!(c.parallax_px > castle.criterion.threshold_px, "{c:?}");
    }
}
