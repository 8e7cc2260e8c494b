//! One method over the run, frame by frame: time by stage (stacked), kept vs inlier counts, the
//! prior's quality (only when the diagnostics carry `prior_quality`), and each frame's outcome
//! with the failure reasons counted by kind.

use std::collections::BTreeMap;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::data::{reason_kind, Outcome, ScoredRun};
use super::figure::{method_colour, DrawResult, Figure, FONT};

const WIDTH: u32 = 1200;
const PANEL_HEIGHT: u32 = 220;
/// Height of the outcome strip above its legend lines.
const STRIP_HEIGHT: u32 = 70;
const LINE_HEIGHT: u32 = 19;
/// Failure-reason kinds listed under the strip.
const MAX_REASONS: usize = 4;
const TITLE_HEIGHT: u32 = 40;
/// Longest failure reason shown in the legend (characters).
const MAX_REASON: usize = 90;

pub const REGISTERED: RGBColor = RGBColor(44, 160, 44);
pub const WRONG_POSE: RGBColor = RGBColor(255, 160, 0);
pub const NO_POSE: RGBColor = RGBColor(214, 39, 40);
const STAGES: [(&str, RGBColor); 4] = [
    ("geometry + prior alignment", RGBColor(31, 119, 180)),
    ("rejection", RGBColor(148, 103, 189)),
    ("PnP + verification", RGBColor(23, 190, 207)),
    ("other", RGBColor(190, 190, 190)),
];

pub struct Timeline<'a> {
    run: &'a ScoredRun,
    colour: RGBColor,
    has_prior_quality: bool,
}

impl<'a> Timeline<'a> {
    pub fn new(run: &'a ScoredRun, index: usize) -> Self {
        let has_prior_quality = run.frames.iter().any(|f| f.record.prior_quality.is_some());
        Timeline { run, colour: method_colour(index), has_prior_quality }
    }

    fn frames(&self) -> std::ops::Range<f64> {
        -0.5..(self.run.frames.len() as f64 - 0.5).max(0.5)
    }

    /// Failure reasons by kind with their counts, most frequent first.
    fn reason_counts(&self) -> Vec<(String, usize)> {
        let mut counts: BTreeMap<String, usize> = BTreeMap::new();
        for f in &self.run.frames {
            let reason = match (f.outcome(), &f.record.failure) {
                (Outcome::NoPose, Some(r)) => reason_kind(r),
                (Outcome::NoPose, None) => "no pose in the output bag".to_string(),
                _ => continue,
            };
            *counts.entry(reason).or_default() += 1;
        }
        let mut v: Vec<(String, usize)> = counts.into_iter().collect();
        v.sort_by(|a, b| b.1.cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
        v
    }
}

impl Figure for Timeline<'_> {
    fn size(&self) -> (u32, u32) {
        let panels = if self.has_prior_quality { 3 } else { 2 };
        let lines = 3 + self.reason_counts().len().min(MAX_REASONS) as u32;
        (WIDTH, TITLE_HEIGHT + panels * PANEL_HEIGHT + STRIP_HEIGHT + lines * LINE_HEIGHT + 15)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        root.fill(&WHITE)?;
        let title = format!("{}: per frame over the run ({} frames)", self.run.label, self.run.frames.len());
        let area = root.titled(&title, (FONT, 22))?;
        let (timing, rest) = area.split_vertically(PANEL_HEIGHT);
        self.draw_timing(&timing)?;
        let (counts, rest) = rest.split_vertically(PANEL_HEIGHT);
        self.draw_counts(&counts)?;
        let outcome = if self.has_prior_quality {
            let (prior, rest) = rest.split_vertically(PANEL_HEIGHT);
            self.draw_prior_quality(&prior)?;
            rest
        } else {
            rest
        };
        self.draw_outcomes(&outcome)
    }
}

impl Timeline<'_> {
    fn draw_timing<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        let stacks: Vec<[f64; 4]> = self
            .run
            .frames
            .iter()
            .map(|f| {
                f.record.stages.map_or([0.0; 4], |s| {
                    [s.geometry, s.reject, s.pnp, (s.total - s.geometry - s.reject - s.pnp).max(0.0)]
                })
            })
            .collect();
        let top = stacks.iter().map(|s| s.iter().sum::<f64>()).fold(0.0, f64::max).max(0.1) * 1.6;
        let mut chart = panel(area, self.frames(), 0.0..top)?;
        mesh(&mut chart, "ms")?;
        for (stage, (name, colour)) in STAGES.iter().enumerate() {
            let colour = *colour;
            chart
                .draw_series(stacks.iter().enumerate().map(|(k, s)| {
                    let below: f64 = s[..stage].iter().sum();
                    let x = k as f64;
                    Rectangle::new([(x - 0.4, below), (x + 0.4, below + s[stage])], colour.filled())
                }))?
                .label(*name)
                .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 12, y + 5)], colour.filled()));
        }
        legend(&mut chart)
    }

    fn draw_counts<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        let frames = &self.run.frames;
        let kept: Vec<f64> = frames.iter().map(|f| f.record.kept_count.unwrap_or(f.record.kept.len()) as f64).collect();
        let pnp: Vec<f64> = frames.iter().map(|f| f.record.pnp_inliers.unwrap_or(0) as f64).collect();
        let truth: Vec<f64> = frames.iter().map(|f| f.true_inliers_kept as f64).collect();
        let top = kept.iter().chain(&pnp).chain(&truth).fold(0.0f64, |a, b| a.max(*b)).max(1.0) * 1.5;
        let mut chart = panel(area, self.frames(), 0.0..top)?;
        mesh(&mut chart, "correspondences")?;
        // Kept is drawn widest, under the others: with `ransac` it equals the PnP inliers.
        let series: [(&str, &Vec<f64>, RGBColor, u32); 3] = [
            ("kept", &kept, self.colour, 5),
            ("PnP inliers", &pnp, BLACK, 2),
            ("true inliers among kept (ground truth, 5 cm)", &truth, REGISTERED, 2),
        ];
        for (name, values, colour, width) in series {
            let points = values.iter().enumerate().map(|(k, v)| (k as f64, *v));
            chart
                .draw_series(LineSeries::new(points.clone(), colour.stroke_width(width)))?
                .label(name)
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], colour.stroke_width(width)));
            chart.draw_series(points.map(|p| Circle::new(p, 2, colour.filled())))?;
        }
        legend(&mut chart)
    }

    fn draw_prior_quality<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        let values: Vec<(f64, f64)> =
            self.run.frames.iter().enumerate().filter_map(|(k, f)| Some((k as f64, f.record.prior_quality?))).collect();
        let (lo, hi) = values.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| (lo.min(p.1), hi.max(p.1)));
        let mut chart = panel(area, self.frames(), super::figure::padded(lo.min(0.0), hi, 0.1))?;
        mesh(&mut chart, "prior_quality")?;
        let colour = self.colour;
        chart
            .draw_series(LineSeries::new(values.iter().copied(), colour.stroke_width(2)))?
            .label("prior quality (from /diagnostics)")
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], colour.stroke_width(2)));
        chart.draw_series(values.iter().map(|p| Circle::new(*p, 2, colour.filled())))?;
        legend(&mut chart)
    }

    fn draw_outcomes<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        let (strip, text) = area.split_vertically(STRIP_HEIGHT);
        let mut chart = ChartBuilder::on(&strip)
            .margin_left(10)
            .margin_right(20)
            .y_label_area_size(60)
            .x_label_area_size(25)
            .build_cartesian_2d(self.frames(), 0.0..1.0)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .disable_y_axis()
            .label_style((FONT, 14))
            .x_label_formatter(&|v| format!("{v:.0}"))
            .draw()?;
        chart.draw_series(self.run.frames.iter().enumerate().map(|(k, f)| {
            let colour = match f.outcome() {
                Outcome::Registered => REGISTERED,
                Outcome::WrongPose => WRONG_POSE,
                Outcome::NoPose => NO_POSE,
            };
            Rectangle::new([(k as f64 - 0.45, 0.0), (k as f64 + 0.45, 1.0)], colour.filled())
        }))?;
        let count = |o: Outcome| self.run.frames.iter().filter(|f| f.outcome() == o).count();
        let mut lines = vec![
            (format!("registered (RMSE < 0.1 m): {}", count(Outcome::Registered)), REGISTERED),
            (format!("pose with RMSE ≥ 0.1 m: {}", count(Outcome::WrongPose)), WRONG_POSE),
            (format!("no pose: {}", count(Outcome::NoPose)), NO_POSE),
        ];
        for (reason, n) in self.reason_counts().into_iter().take(MAX_REASONS) {
            let short: String = reason.chars().take(MAX_REASON).collect();
            let ellipsis = if reason.chars().count() > MAX_REASON { "…" } else { "" };
            lines.push((format!("    {n} × {short}{ellipsis}"), NO_POSE));
        }
        for (row, (line, colour)) in lines.iter().enumerate() {
            let y = 8 + (LINE_HEIGHT * row as u32) as i32;
            text.draw(&Rectangle::new([(70, y + 2), (82, y + 14)], colour.filled()))?;
            text.draw(&Text::new(line.as_str(), (90, y), (FONT, 15).into_font().color(&BLACK)))?;
        }
        Ok(())
    }
}

type Chart<'a, DB> =
    ChartContext<'a, DB, Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>>;

fn panel<'a, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, Shift>,
    x: std::ops::Range<f64>,
    y: std::ops::Range<f64>,
) -> Result<Chart<'a, DB>, DrawingAreaErrorKind<DB::ErrorType>> {
    ChartBuilder::on(area)
        .margin(10)
        .margin_right(20)
        .x_label_area_size(35)
        .y_label_area_size(60)
        .build_cartesian_2d(x, y)
}

fn mesh<'a, DB: DrawingBackend + 'a>(chart: &mut Chart<'a, DB>, y: &str) -> DrawResult<DB> {
    chart
        .configure_mesh()
        .y_desc(y)
        .x_desc("frame")
        .label_style((FONT, 14))
        .axis_desc_style((FONT, 15))
        .x_label_formatter(&|v| format!("{v:.0}"))
        .draw()
}

fn legend<'a, DB: DrawingBackend + 'a>(chart: &mut Chart<'a, DB>) -> DrawResult<DB> {
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font((FONT, 13))
        .draw()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::{FrameMetrics, PoseErrors, Summary};
    use crate::report::data::{FrameRecord, ScoredFrame, StageMs};
    use crate::report::figure::{register_font, render_bitmap};

    fn run(prior_quality: Option<f64>) -> ScoredRun {
        let frame = |k: usize, rmse: Option<f64>, failure: Option<&str>| ScoredFrame {
            frame_index: k,
            metrics: FrameMetrics {
                stamp: k as i64,
                inlier_ratio: 0.5,
                errors: rmse.map(|r| PoseErrors { rotation_deg: 1.0, translation_m: r, rmse_m: r, nees: None }),
                ms: Some(3.0),
            },
            record: FrameRecord {
                stages: Some(StageMs { geometry: 1.0, reject: 1.0, pnp: 0.5, total: 3.0 }),
                kept_count: Some(40),
                pnp_inliers: Some(20),
                prior_quality,
                failure: failure.map(str::to_string),
                ..Default::default()
            },
            true_inliers_kept: 18,
        };
        ScoredRun {
            label: "m".into(),
            summary: Summary::default(),
            frames: vec![
                frame(0, Some(0.01), None),
                frame(1, Some(0.5), None),
                frame(2, None, Some("PnP failed: 3 < 6")),
                frame(3, None, Some("PnP failed: 2 < 6")),
            ],
            unscored_failures: Vec::new(),
        }
    }

    #[test]
    fn outcomes_are_coloured_and_the_prior_panel_only_when_reported() {
        register_font().unwrap();
        let without = run(None);
        let with = run(Some(0.7));
        let (plain, prior) = (Timeline::new(&without, 0), Timeline::new(&with, 0));
        assert_eq!(plain.reason_counts(), [("PnP failed: # < #".to_string(), 2)]);
        assert_eq!(prior.size().1, plain.size().1 + PANEL_HEIGHT);
        let img = render_bitmap(&plain).unwrap();
        for colour in [REGISTERED, WRONG_POSE, NO_POSE] {
            let n = img.pixels().filter(|p| p.0 == [colour.0, colour.1, colour.2]).count();
            assert!(n > 1000, "{colour:?}: {n} pixels");
        }
        assert!(render_bitmap(&prior).is_ok());
    }
}
