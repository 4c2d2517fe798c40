use super::*;
use tracks::TrackSet;

/// `ew` along x crossing `ns` along z at the origin; `spur` leaves `ew`'s east end north.
fn town() -> Network {
    let set = TrackSet::parse(
        r#"
        [[track]]
        name = "ew"
        points = [[-10, 1.7, 0], [0, 1.7, 0], [10, 1.7, 0]]
        spacing = 2.5
        [[track]]
        name = "ns"
        points = [[0, 1.7, -10], [0, 1.7, 10]]
        spacing = 2.5
        [[track]]
        name = "spur"
        points = [[10, 1.7, 0], [10, 1.7, -8]]
        spacing = 2.0
        "#,
        "town.toml",
    )
    .unwrap();
    Network::new(set.tracks).unwrap()
}

#[test]
fn at_a_crossing_the_walker_takes_the_branch_nearest_the_view() {
    let net = town();
    let mut w = Walker::new(0, 5.0, true);
    // Looking south (−z) as it reaches the crossing at s = 10: it turns onto `ns`, backwards.
    let turns = w.advance(&net, 7.0, DVec3::NEG_Z);
    assert_eq!(turns.len(), 1);
    assert_eq!(w.pos.track, 1);
    assert!(!w.forward);
    assert!((w.pos.s - 8.0).abs() < 1e-9, "{:?}", w.pos);
    // Looking along the track: straight on.
    let mut w = Walker::new(0, 5.0, true);
    assert!(w.advance(&net, 7.0, DVec3::X).is_empty());
    assert_eq!((w.pos.track, w.pos.s), (0, 12.0));
}

#[test]
fn a_chosen_branch_wins_over_the_view_and_is_used_once() {
    let net = town();
    let mut w = Walker::new(0, 5.0, true);
    let options = w.options(&net);
    assert_eq!(options.len(), 3, "{options:?}");
    let north = *options
        .iter()
        .find(|b| net.branch_heading(b).dot(DVec3::Z) > 0.9)
        .unwrap();
    w.chosen = Some(north);
    w.advance(&net, 6.0, DVec3::X);
    assert_eq!(w.pos.track, 1);
    assert!(w.forward);
    assert_eq!(w.chosen, None);
}

#[test]
fn standing_on_a_junction_after_a_turn_does_not_turn_again() {
    let net = town();
    let mut w = Walker::new(0, 5.0, true);
    w.advance(&net, 5.0, DVec3::Z);
    assert_eq!(w.pos.track, 1);
    let at = w.pos;
    // Looking back west now: the walker walks on along `ns`, it does not turn onto `ew`.
    w.advance(&net, 1.0, DVec3::NEG_X);
    assert_eq!(w.pos.track, 1);
    assert!((w.pos.s - at.s - 1.0).abs() < 1e-9);
}

#[test]
fn branch_weights_sum_to_one_and_follow_the_view() {
    let net = town();
    let w = Walker::new(0, 5.0, true);
    let ways = w.options(&net);
    let weights = branch_weights(&net, &ways, DVec3::Z, DVec3::X, None);
    let total: f64 = weights.iter().map(|x| x.1).sum();
    assert!((total - 1.0).abs() < 1e-12);
    let best = weights.iter().max_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
    assert!(net.branch_heading(&best.0).dot(DVec3::Z) > 0.9);
    let west = ways
        .iter()
        .find(|b| net.branch_heading(b).dot(DVec3::X) > 0.9)
        .copied();
    let chosen = branch_weights(&net, &ways, DVec3::Z, DVec3::X, west.as_ref());
    let top = chosen.iter().max_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
    assert_eq!(Some(top.0), west);
}

#[test]
fn a_route_follows_its_tracks_and_joins_them_at_their_junctions() {
    let net = town();
    let r = Route::new(&net, &["ns", "ew", "spur"]).unwrap();
    assert_eq!(r.legs.len(), 3);
    assert!((r.length() - (10.0 + 10.0 + 8.0)).abs() < 1e-9, "{r:?}");
    let turns = r.turn_distances();
    assert_eq!(turns.len(), 2);
    // Both sides of a turn are the junction's viewpoint.
    for (k, &d) in turns.iter().enumerate() {
        let (before, _) = r.at(d);
        let (after, _) = r.at(d + 1e-12);
        let p = |x: NetPos| net.tracks[x.track].position_at(x.s);
        assert!(p(before).distance(p(after)) < 1e-6, "turn {k}");
        assert!(p(before).distance(net.viewpoints[r.turns[k]]) < 1e-6);
    }
    let e = Route::new(&net, &["ns", "spur"]).unwrap_err();
    assert!(e.contains("`ns` and `spur` do not meet"), "{e}");
    let e = Route::new(&net, &["ns", "nowhere"]).unwrap_err();
    assert!(e.contains("no track `nowhere`"), "{e}");
}
