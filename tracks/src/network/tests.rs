use super::*;
use crate::track::{Smoothing, TrackSet};

fn net(text: &str) -> Result<Network, TrackError> {
    Network::new(TrackSet::parse(text, "streets.toml")?.tracks)
}

#[test]
fn one_track_is_numbered_as_alone() {
    let set = TrackSet::parse(
        r#"
        [[track]]
        name = "main"
        points = [[0, 1.7, 42], [0, 1.7, 0], [14, 1.7, 0], [14, 1.7, -16]]
        spacing = 2.0
        "#,
        "t.toml",
    )
    .unwrap();
    let t = set.tracks[0].clone();
    let n = Network::new(set.tracks).unwrap();
    let alone = t.viewpoints();
    assert_eq!(n.viewpoints.len(), alone.len());
    for (v, a) in alone.iter().enumerate() {
        assert_eq!(n.viewpoints[v], a.position, "viewpoint {v}");
        assert_eq!(
            n.stops[0][v],
            Stop {
                viewpoint: v,
                s: a.s
            }
        );
    }
    assert!(n.junctions.is_empty());
    assert_eq!(n.segments.len(), alone.len() - 1);
    assert_eq!(n.incident(0), &[0]);
    assert_eq!(n.incident(3), &[2, 3]);
}

#[test]
fn a_crossing_of_two_straight_tracks_is_one_viewpoint_with_four_branches() {
    let n = net(r#"
        [[track]]
        name = "ew"
        points = [[-9, 1.7, 0], [0, 1.7, 0], [9, 1.7, 0]]
        spacing = 2.0
        [[track]]
        name = "ns"
        points = [[0, 1.7, -9], [0, 1.7, 9]]
        spacing = 2.0
        "#)
    .unwrap();
    assert_eq!(n.junctions.len(), 1);
    let j = &n.junctions[0];
    assert_eq!(n.viewpoints[j.viewpoint], DVec3::new(0.0, 1.7, 0.0));
    assert_eq!(j.branches.len(), 4);
    // Both tracks stop there, at their own arc lengths.
    assert_eq!(n.arcs_of(0, j.viewpoint), vec![9.0]);
    assert_eq!(n.arcs_of(1, j.viewpoint), vec![9.0]);
    // Spacing holds on each piece between an end and the junction.
    for t in 0..2 {
        let arcs = n.stop_arcs(t);
        assert!(arcs.windows(2).all(|w| w[1] - w[0] <= 2.0 + 1e-12));
    }
    // The junction's cell reaches along all four branches.
    assert_eq!(n.cell_paths(j.viewpoint).len(), 4);
    assert_eq!(n.neighbours(j.viewpoint).len(), 4);
    let headings: Vec<DVec3> = j.branches.iter().map(|b| n.branch_heading(b)).collect();
    for h in [DVec3::X, -DVec3::X, DVec3::Z, -DVec3::Z] {
        assert!(
            headings.iter().any(|g| g.distance(h) < 1e-12),
            "{h} missing"
        );
    }
    // Five pieces each side of the crossing on each track (11 stops), one viewpoint shared.
    assert_eq!(n.viewpoints.len(), 21);
}

#[test]
fn the_junction_is_drawn_alike_from_every_track() {
    let n = net(r#"
        [[track]]
        name = "a"
        points = [[0, 1.7, 0], [10, 1.7, 0]]
        spacing = 3.0
        [[track]]
        name = "b"
        points = [[10, 1.7, 0], [10, 1.7, 8]]
        spacing = 3.0
        "#)
    .unwrap();
    let j = n.junctions[0].viewpoint;
    let (a0, a1, wa) = n.blend_pair(0, 10.0).unwrap();
    let (b0, b1, wb) = n.blend_pair(1, 0.0).unwrap();
    // At the junction one view carries all the weight, and it is the junction's.
    let heavy_a = if wa == 0.0 { a0 } else { a1 };
    let heavy_b = if wb == 0.0 { b0 } else { b1 };
    assert_eq!((heavy_a, heavy_b), (j, j));
    let seg = n.segment_at(1, 1.0).unwrap();
    assert_eq!(n.segments[seg].from, j);
    let path = n.segment_path(seg);
    assert_eq!(path.first(), Some(&n.viewpoints[j]));
}

#[test]
fn count_is_shared_between_the_pieces_of_a_track() {
    let n = net(r#"
        [[track]]
        name = "a"
        points = [[0, 0, 0], [3, 0, 0], [12, 0, 0]]
        count = 5
        [[track]]
        name = "b"
        points = [[3, 0, 0], [3, 0, 5]]
        count = 2
        "#)
    .unwrap();
    let arcs = n.stop_arcs(0);
    assert_eq!(arcs.len(), 5);
    assert!(arcs.contains(&3.0));
    let few = net(r#"
        [[track]]
        name = "a"
        points = [[0, 0, 0], [3, 0, 0], [6, 0, 0], [12, 0, 0]]
        count = 2
        [[track]]
        name = "b"
        points = [[3, 0, 0], [3, 0, 5]]
        count = 2
        [[track]]
        name = "c"
        points = [[6, 0, 0], [6, 0, 5]]
        count = 2
        "#)
    .unwrap_err()
    .to_string();
    assert!(
        few.contains("streets.toml:2") && few.contains("count"),
        "{few}"
    );
}

#[test]
fn an_end_that_almost_meets_a_track_is_refused_with_file_line_and_distance() {
    let e = net(r#"
        [[track]]
        name = "a"
        points = [[0, 1.7, 0], [10, 1.7, 0]]
        spacing = 2.0

        [[track]]
        name = "b"
        points = [[5, 1.7, 0.05], [5, 1.7, 8]]
        spacing = 2.0
        "#)
    .unwrap_err()
    .to_string();
    assert!(e.contains("streets.toml:7"), "{e}");
    assert!(e.contains("track `b`") && e.contains("`a`"), "{e}");
    assert!(e.contains("0.0500 m"), "{e}");
}

#[test]
fn tracks_that_cross_without_a_shared_point_are_refused() {
    let e = net(r#"
        [[track]]
        name = "a"
        points = [[-5, 1.7, 0], [5, 1.7, 0]]
        spacing = 2.0
        [[track]]
        name = "b"
        points = [[0, 1.7, -5], [0, 1.7, 5]]
        spacing = 2.0
        "#)
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("crosses track `b`") && e.contains("streets.toml:2"),
        "{e}"
    );
    let near = net(r#"
        [[track]]
        name = "a"
        points = [[-5, 1.7, 0], [5, 1.7, 0]]
        spacing = 2.0
        [[track]]
        name = "b"
        points = [[-5, 1.8, -5], [5, 1.8, 5]]
        spacing = 2.0
        "#)
    .unwrap_err()
    .to_string();
    assert!(near.contains("passes 0.1000 m from"), "{near}");
}

#[test]
fn a_shallow_branch_near_its_junction_is_not_a_near_miss() {
    let n = net(r#"
        [[track]]
        name = "a"
        points = [[0, 0, 0], [20, 0, 0]]
        spacing = 2.0
        [[track]]
        name = "b"
        points = [[10, 0, 0], [14, 0, 0.6], [20, 0, 6]]
        spacing = 2.0
        "#)
    .unwrap();
    assert_eq!(n.junctions.len(), 1);
}

#[test]
fn a_loop_meets_itself() {
    let n = net(r#"
        [[track]]
        name = "ring"
        points = [[0, 0, 0], [10, 0, 0], [10, 0, 10], [0, 0, 10], [0, 0, 0]]
        spacing = 5.0
        "#)
    .unwrap();
    let st = &n.stops[0];
    assert_eq!(st.first().unwrap().viewpoint, st.last().unwrap().viewpoint);
    assert_eq!(n.viewpoints.len(), st.len() - 1);
    assert_eq!(n.junctions.len(), 1);
    assert_eq!(n.junctions[0].branches.len(), 2);
}

#[test]
fn a_smoothed_track_joins_at_its_control_points() {
    let a = Track::new(
        "a",
        vec![
            DVec3::ZERO,
            DVec3::new(5.0, 0.0, 1.0),
            DVec3::new(10.0, 0.0, 0.0),
        ],
        Smoothing::CatmullRom,
        Sampling::Spacing(1.5),
        "code",
    )
    .unwrap();
    let b = Track::new(
        "b",
        vec![DVec3::new(5.0, 0.0, 1.0), DVec3::new(5.0, 0.0, 9.0)],
        Smoothing::None,
        Sampling::Spacing(1.5),
        "code",
    )
    .unwrap();
    let n = Network::new(vec![a, b]).unwrap();
    assert_eq!(n.junctions.len(), 1);
    assert_eq!(
        n.viewpoints[n.junctions[0].viewpoint],
        DVec3::new(5.0, 0.0, 1.0)
    );
}

#[test]
fn segment_distance_is_exact_on_simple_cases() {
    let (d, a, b) = closest_between_segments(
        DVec3::new(-1.0, 0.0, 0.0),
        DVec3::new(1.0, 0.0, 0.0),
        DVec3::new(0.0, 1.0, -1.0),
        DVec3::new(0.0, 1.0, 1.0),
    );
    assert!((d - 1.0).abs() < 1e-12);
    assert!(a.distance(DVec3::ZERO) < 1e-12 && b.distance(DVec3::Y) < 1e-12);
    let (d, ..) = closest_between_segments(
        DVec3::ZERO,
        DVec3::X,
        DVec3::new(2.0, 0.0, 0.0),
        DVec3::new(3.0, 0.0, 0.0),
    );
    assert!((d - 1.0).abs() < 1e-12);
}
