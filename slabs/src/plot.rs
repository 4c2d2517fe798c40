//! The histogram plot: the track's depth histogram over a log depth axis with the chosen slab
//! boundaries and the rejected candidates marked, drawn with [`charts`] (SVG and PNG).

use charts::{Axis, Chart, Figure, Marker, Series};
use tracks::SlabRange;

use crate::histogram::DepthHistogram;

/// The figure of `hist`: one bar per bin (steradians of the average panorama per bin), a
/// solid line at each boundary of `slabs` (their finite `near` values above 0) and a dashed
/// one at each rejected candidate depth in `rejected_m`.
pub fn histogram_figure(hist: &DepthHistogram, slabs: &[SlabRange], rejected_m: &[f64]) -> Figure {
    let bins = hist.bins();
    let span = hist.log10_max - hist.log10_min;
    let edge = |i: usize| 10f64.powf(hist.log10_min + span * i as f64 / bins as f64);
    let bars: Vec<(f64, f64, f64)> = hist
        .weights
        .iter()
        .enumerate()
        .filter(|(_, w)| **w > 0.0)
        .map(|(i, &w)| (edge(i), edge(i + 1), w))
        .collect();
    let mut chart = Chart::new("Depth histogram of the track and slab boundaries")
        .x(Axis::log("radial depth (m)"))
        .y(Axis::linear("solid angle per viewpoint (sr)"))
        .series(Series::bars("surfaces at this depth", bars).color(7));
    let boundaries: Vec<f64> = slabs
        .iter()
        .map(|s| s.near)
        .filter(|d| *d > 0.0 && d.is_finite())
        .collect();
    for (i, &d) in boundaries.iter().enumerate() {
        chart = chart.marker(Marker {
            x: d,
            name: if i == 0 {
                "slab boundary".into()
            } else {
                String::new()
            },
            color: 3,
            dashed: false,
        });
    }
    for (i, &d) in rejected_m.iter().filter(|d| **d > 0.0).enumerate() {
        chart = chart.marker(Marker {
            x: d,
            name: if i == 0 {
                "rejected candidate".into()
            } else {
                String::new()
            },
            color: 0,
            dashed: true,
        });
    }
    Figure::single(chart)
}

#[cfg(test)]
mod tests {
    use super::*;
    use tracks::{CubeMap, Face};

    #[test]
    fn boundaries_and_bars_are_in_the_figure() {
        let m = CubeMap::from_fn(8, |f, _, _| if f == Face::PosX { 2.0 } else { 50.0 });
        let h = DepthHistogram::build(&[m], 64);
        let slabs = SlabRange::parse_list("0-10,10-inf").unwrap();
        let fig = histogram_figure(&h, &slabs, &[20.0]);
        let chart = &fig.panels[0];
        assert_eq!(chart.markers.len(), 2);
        assert_eq!(chart.markers[0].x, 10.0);
        assert!(!chart.markers[0].dashed && chart.markers[1].dashed);
        let charts::Kind::Bars(bars) = &chart.series[0].kind else {
            panic!("bars expected");
        };
        // Two depths: two occupied bins, each bar inside the histogram's range.
        assert_eq!(bars.len(), 2);
        assert!(bars.iter().all(|b| b.0 < b.1 && b.2 > 0.0));
        let svg = charts::svg(&fig).unwrap();
        assert!(svg.contains("radial depth (m)") && svg.contains("slab boundary"));
        assert!(charts::png(&fig).unwrap().starts_with(b"\x89PNG"));
    }
}
