//! Published curves drawn beside our runs: each dashed, in its own dark colour, with its ± std
//! as a faint band (a dense curve) or as bars at its points (a sparse one, [`Reading::AtPoints`]:
//! a band between points 100k apart would draw figures nobody measured).

use crate::paper_curve::{PaperCurve, Reading};
use crate::PanelChart;
use plotters::prelude::*;

/// The colours of the published curves, in the order given: black first (the MBPO authors'
/// curve when there is one), then dark tones apart from the runs' bright palette.
const COLORS: [RGBColor; 6] = [
    RGBColor(0, 0, 0),
    RGBColor(140, 60, 20),
    RGBColor(90, 40, 130),
    RGBColor(30, 100, 60),
    RGBColor(120, 120, 120),
    RGBColor(150, 20, 90),
];

/// A published curve with its points inside a panel: (env steps, mean, std).
pub(crate) type ReferencePoints<'r> = (&'r PaperCurve, Vec<(f64, f64, f64)>);

/// The part of `reference` over the env steps `x0..=x1` as (env steps, mean, std): a dense
/// curve with its ends interpolated, a sparse one at its points only (empty where the curve has
/// no points in that range).
pub(crate) fn within(reference: &PaperCurve, x0: f64, x1: f64) -> Vec<(f64, f64, f64)> {
    let inside = reference
        .points
        .iter()
        .map(|p| (p.env_steps as f64, p.mean, p.std));
    if reference.reading == Reading::AtPoints {
        return inside.filter(|&(s, _, _)| x0 <= s && s <= x1).collect();
    }
    let end = |x: f64| reference.at(x as u64).map(|p| (x, p.mean, p.std));
    end(x0)
        .into_iter()
        .chain(inside.filter(|&(s, _, _)| x0 < s && s < x1))
        .chain(end(x1))
        .collect()
}

/// Draw each of `references` with its points inside the panel (from [`within`]); the mean only
/// on a log scale.
pub(crate) fn draw_references(
    chart: &mut PanelChart<'_, '_>,
    references: &[ReferencePoints<'_>],
    log: bool,
    legend_inside: bool,
) -> Result<(), String> {
    let tf = |y: f64| if log { y.log10() } else { y };
    for (i, (reference, points)) in references.iter().enumerate() {
        // A curve with no point over the runs' steps (TD-MPC2's first after 0 is at 100k) is
        // not in the legend either: a name without a mark would say it is drawn.
        if points.is_empty() {
            continue;
        }
        let color = COLORS[i % COLORS.len()];
        draw_spread(chart, reference.reading, points, color, log)?;
        let style = color.stroke_width(2);
        let line = chart
            .draw_series(DashedLineSeries::new(
                points.iter().map(|&(x, mean, _)| (x, tf(mean))),
                8,
                6,
                style,
            ))
            .map_err(|e| e.to_string())?;
        if legend_inside {
            line.label(reference.label.as_str())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
        }
    }
    Ok(())
}

/// A curve's ± std: a faint band under a dense curve, a marker with a bar at each point of a
/// sparse one (only the marker on a log scale).
fn draw_spread(
    chart: &mut PanelChart<'_, '_>,
    reading: Reading,
    points: &[(f64, f64, f64)],
    color: RGBColor,
    log: bool,
) -> Result<(), String> {
    let e = |e: plotters::drawing::DrawingAreaErrorKind<_>| e.to_string();
    let tf = |y: f64| if log { y.log10() } else { y };
    let spread = |std: f64| if log { 0.0 } else { std };
    if reading == Reading::AtPoints {
        for &(x, mean, std) in points {
            let bar = [(x, tf(mean - spread(std))), (x, tf(mean + spread(std)))];
            chart
                .draw_series(std::iter::once(PathElement::new(
                    bar,
                    color.stroke_width(2),
                )))
                .map_err(e)?;
            chart
                .draw_series(std::iter::once(Circle::new(
                    (x, tf(mean)),
                    5,
                    color.filled(),
                )))
                .map_err(e)?;
        }
        return Ok(());
    }
    let band: Vec<(f64, f64)> = points
        .iter()
        .map(|&(x, mean, std)| (x, tf(mean + spread(std))))
        .chain(
            points
                .iter()
                .rev()
                .map(|&(x, mean, std)| (x, tf(mean - spread(std)))),
        )
        .collect();
    chart
        .draw_series(std::iter::once(Polygon::new(
            band,
            color.mix(0.07).filled(),
        )))
        .map_err(e)?;
    Ok(())
}
