//! Cumulative error curves: for each error bound on a log axis, the share of all scored frames
//! whose error is within it (a frame without a pose never is, so curves top out at the share
//! with a pose). Three panels: rotation, translation, and the RMSE that decides RR, where the
//! RR threshold is drawn — each curve crosses it at that method's RR.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::data::ScoredRuns;
use super::figure::{method_colour, DrawResult, Figure, FONT};
use crate::eval::RECALL_THRESHOLD;

const SIZE: (u32, u32) = (1350, 450);

/// Which error a panel shows.
#[derive(Clone, Copy)]
enum ErrorKind {
    Rotation,
    Translation,
    Rmse,
}

impl ErrorKind {
    fn title(self) -> &'static str {
        match self {
            ErrorKind::Rotation => "rotation error (deg)",
            ErrorKind::Translation => "translation error (m)",
            ErrorKind::Rmse => "RMSE of the frame's points (m)",
        }
    }
}

struct Curve {
    label: String,
    colour: RGBColor,
    /// Sorted errors of the frames with a pose.
    errors: [Vec<f64>; 3],
    /// Frames scored (with or without a pose).
    frames: usize,
    rr: f64,
}

pub struct CumulativeErrors {
    curves: Vec<Curve>,
}

impl CumulativeErrors {
    pub fn new(scored: &ScoredRuns) -> Self {
        let curves = scored
            .runs
            .iter()
            .enumerate()
            .map(|(i, run)| {
                let sorted = |f: &dyn Fn(&crate::eval::PoseErrors) -> f64| {
                    let mut v: Vec<f64> = run
                        .frames
                        .iter()
                        .filter_map(|s| s.metrics.errors.as_ref().map(f))
                        .filter(|e| e.is_finite())
                        .collect();
                    v.sort_by(f64::total_cmp);
                    v
                };
                Curve {
                    label: run.label.clone(),
                    colour: method_colour(i),
                    errors: [sorted(&|e| e.rotation_deg), sorted(&|e| e.translation_m), sorted(&|e| e.rmse_m)],
                    frames: run.frames.len(),
                    rr: run.summary.rr,
                }
            })
            .collect();
        CumulativeErrors { curves }
    }

    /// Log-axis range over every curve's errors of panel `k`, whole decades, holding `must`.
    fn range(&self, k: usize, must: Option<f64>) -> std::ops::Range<f64> {
        let all = self.curves.iter().flat_map(|c| c.errors[k].iter().copied()).filter(|e| *e > 0.0);
        let (lo, hi) = all.chain(must).fold((f64::INFINITY, 0.0f64), |(lo, hi), e| (lo.min(e), hi.max(e)));
        if !lo.is_finite() || hi <= 0.0 {
            return 1e-3..1.0;
        }
        let lo = 10f64.powf(lo.log10().floor()).max(1e-6);
        let hi = 10f64.powf(hi.log10().ceil()).max(lo * 10.0);
        lo..hi
    }
}

/// The step curve of `errors` (sorted) over `range`, in % of `frames`.
fn steps(errors: &[f64], frames: usize, range: &std::ops::Range<f64>) -> Vec<(f64, f64)> {
    let share = |k: usize| 100.0 * k as f64 / frames.max(1) as f64;
    let mut points = vec![(range.start, 0.0)];
    for (k, e) in errors.iter().enumerate() {
        let x = e.clamp(range.start, range.end);
        points.push((x, share(k)));
        points.push((x, share(k + 1)));
    }
    points.push((range.end, share(errors.len())));
    points
}

impl Figure for CumulativeErrors {
    fn size(&self) -> (u32, u32) {
        SIZE
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        root.fill(&WHITE)?;
        let titled = root.titled("Cumulative pose errors (share of all frames; no pose = never within)", (FONT, 22))?;
        let panels = titled.split_evenly((1, 3));
        for (k, (panel, kind)) in
            panels.iter().zip([ErrorKind::Rotation, ErrorKind::Translation, ErrorKind::Rmse]).enumerate()
        {
            self.draw_panel(panel, k, kind)?;
        }
        Ok(())
    }
}

impl CumulativeErrors {
    fn draw_panel<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
        k: usize,
        kind: ErrorKind,
    ) -> DrawResult<DB> {
        let threshold = matches!(kind, ErrorKind::Rmse).then_some(RECALL_THRESHOLD);
        // The threshold inside the axis, not on its edge.
        let range = self.range(k, threshold.map(|t| t * 2.0));
        let mut chart = ChartBuilder::on(area)
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(55)
            .build_cartesian_2d(range.clone().log_scale(), 0.0..100.0)?;
        chart
            .configure_mesh()
            .x_desc(kind.title())
            .y_desc("frames within (%)")
            .label_style((FONT, 14))
            .axis_desc_style((FONT, 15))
            .x_label_formatter(&|v| format!("{v}"))
            .y_label_formatter(&|v| format!("{v:.0}"))
            .draw()?;
        if let Some(t) = threshold {
            chart
                .draw_series(LineSeries::new([(t, 0.0), (t, 100.0)], BLACK.stroke_width(2)))?
                .label(format!("RR threshold {t} m"))
                .legend(|(x, y)| PathElement::new([(x, y), (x + 16, y)], BLACK.stroke_width(2)));
        }
        for c in &self.curves {
            let colour = c.colour;
            let label = if threshold.is_some() { format!("{} (RR {:.1} %)", c.label, c.rr) } else { c.label.clone() };
            chart
                .draw_series(LineSeries::new(steps(&c.errors[k], c.frames, &range), colour.stroke_width(2)))?
                .label(label)
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], colour.stroke_width(2)));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font((FONT, 13))
            .draw()?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steps_reach_the_share_with_a_pose() {
        let s = steps(&[0.05, 0.2], 4, &(0.01..1.0));
        assert_eq!(s.first(), Some(&(0.01, 0.0)));
        assert_eq!(s.last(), Some(&(1.0, 50.0)));
        // Within the RR threshold: one frame of four.
        let at = s.iter().filter(|(x, _)| *x <= 0.1).map(|p| p.1).fold(0.0, f64::max);
        assert_eq!(at, 25.0);
    }
}
