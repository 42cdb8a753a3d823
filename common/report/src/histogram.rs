//! A histogram as a bar chart (log-scaled counts, so a rare slow bin is as visible as the
//! common fast ones): a paced run's step-interval errors (`pacing.png`).

use plotters::prelude::*;
use std::path::Path;

use crate::{register_font, PlotError};

/// One bar: its label (the bin's range) and its count.
#[derive(Debug, Clone, PartialEq)]
pub struct Bar {
    /// What the bin holds, e.g. `< 5 us`.
    pub label: String,
    /// How many.
    pub count: u64,
}

/// Draw `bars` to a PNG with `title` and the x axis named `x_label`.
pub fn plot_histogram(
    bars: &[Bar],
    title: &str,
    x_label: &str,
    out: &Path,
) -> Result<(), PlotError> {
    if bars.iter().all(|b| b.count == 0) {
        return Err(PlotError::Empty);
    }
    register_font();
    let draw_err = |message: String| PlotError::Draw {
        path: out.to_path_buf(),
        message,
    };
    let root = BitMapBackend::new(out, (960, 540)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| draw_err(e.to_string()))?;
    let top = bars.iter().map(|b| b.count).max().unwrap_or(1) as f64;
    let n = bars.len() as f64;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 24))
        .margin(16)
        .x_label_area_size(70)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..n, (0.8..top * 2.0).log_scale())
        .map_err(|e| draw_err(e.to_string()))?;
    let label_of = |x: &f64| {
        let i = x.floor() as usize;
        let centre = (x - x.floor() - 0.5).abs() < 1e-6;
        match (centre, bars.get(i)) {
            (true, Some(b)) => b.label.clone(),
            _ => String::new(),
        }
    };
    chart
        .configure_mesh()
        .x_labels(bars.len() * 2 + 1)
        .x_label_formatter(&label_of)
        .x_label_style(("sans-serif", 13))
        .x_desc(x_label)
        .y_desc("steps (log scale)")
        .disable_x_mesh()
        .draw()
        .map_err(|e| draw_err(e.to_string()))?;
    let rects = bars
        .iter()
        .enumerate()
        .filter(|(_, b)| b.count > 0)
        .map(|(i, b)| {
            let x = i as f64;
            Rectangle::new(
                [(x + 0.1, 0.8), (x + 0.9, b.count as f64)],
                BLUE.mix(0.7).filled(),
            )
        });
    chart
        .draw_series(rects)
        .map_err(|e| draw_err(e.to_string()))?;
    root.present().map_err(|e| draw_err(e.to_string()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_histogram_is_drawn_and_an_empty_one_refused() {
        let dir = std::env::temp_dir().join(format!("mbpo-hist-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let out = dir.join("h.png");
        let bar = |label: &str, count| Bar {
            label: label.into(),
            count,
        };
        let bars = [bar("< 2 us", 900), bar("2..5 us", 90), bar("> 100 ms", 1)];
        plot_histogram(&bars, "errors", "error", &out).unwrap();
        assert!(std::fs::metadata(&out).unwrap().len() > 1000);
        let empty = [bar("< 2 us", 0)];
        assert!(matches!(
            plot_histogram(&empty, "e", "e", &dir.join("e.png")),
            Err(PlotError::Empty)
        ));
        std::fs::remove_dir_all(dir).unwrap();
    }
}
