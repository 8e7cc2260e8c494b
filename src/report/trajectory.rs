//! The camera path seen from above: map points faint, the ground-truth path, each method's
//! estimated positions (filled: registered, hollow and tied to the truth: over the RR
//! threshold) and a cross at the true position of every frame a method got no pose for.
//!
//! "Above" is against the cameras' mean down direction (image rows point down in the optical
//! frame): the map axis closest to it is dropped, the other two are plotted at equal scale.

use nalgebra::{Point3, Vector3};
use plotters::coord::Shift;
use plotters::prelude::*;

use super::data::{Outcome, ScoredRuns};
use super::figure::{method_colour, padded, DrawResult, Figure, FONT};
use crate::bag::BagFrames;

/// At most this many map points are drawn (an even subsample of the map).
const MAX_MAP_POINTS: usize = 15_000;
const SIZE: (u32, u32) = (900, 820);
/// Plot area inside the figure (label areas and margins subtracted), for equal axis scales.
const PLOT_AREA: (f64, f64) = (900.0 - 70.0 - 30.0, 820.0 - 50.0 - 50.0 - 30.0);

/// One method's positions, per scored frame.
struct MethodPath {
    label: String,
    colour: RGBColor,
    frames: Vec<FramePosition>,
}

/// Where one frame is, in the plotted plane.
struct FramePosition {
    truth: [f64; 2],
    estimate: Option<[f64; 2]>,
    outcome: Outcome,
}

pub struct Trajectory {
    axes: [usize; 2],
    truth: Vec<[f64; 2]>,
    map: Vec<[f64; 2]>,
    methods: Vec<MethodPath>,
    range: [std::ops::Range<f64>; 2],
}

const AXIS_NAMES: [&str; 3] = ["x", "y", "z"];

impl Trajectory {
    pub fn new(bag: &BagFrames, scored: &ScoredRuns) -> Self {
        let poses: Vec<_> =
            scored.frame_indices.iter().filter_map(|&k| bag.frames.get(k)?.ground_truth.as_ref()?.pose).collect();
        let down: Vector3<f64> = poses.iter().map(|p| p.rotation * Vector3::y()).sum();
        let vertical = (0..3).max_by(|&a, &b| down[a].abs().total_cmp(&down[b].abs())).unwrap_or(2);
        let axes = match vertical {
            0 => [1, 2],
            1 => [0, 2],
            _ => [0, 1],
        };
        let flat = |p: &Point3<f64>| [p[axes[0]], p[axes[1]]];
        let truth: Vec<[f64; 2]> = poses.iter().map(|p| flat(&p.translation.vector.into())).collect();
        let map: Vec<[f64; 2]> = bag.map.as_ref().map_or_else(Vec::new, |m| {
            let stride = m.points.len().div_ceil(MAX_MAP_POINTS).max(1);
            m.points.iter().step_by(stride).map(|p| flat(&p.cast::<f64>())).collect()
        });
        let methods = scored
            .runs
            .iter()
            .enumerate()
            .map(|(i, run)| MethodPath {
                label: run.label.clone(),
                colour: method_colour(i),
                frames: run
                    .frames
                    .iter()
                    .zip(&truth)
                    .map(|(f, t)| FramePosition {
                        truth: *t,
                        estimate: f.record.pose.map(|p| flat(&p.translation.vector.into())),
                        outcome: f.outcome(),
                    })
                    .collect(),
            })
            .collect();
        let range = view_range(&truth, &map);
        Trajectory { axes, truth, map, methods, range }
    }
}

/// The truth and the bulk of the map (2nd–98th percentile per axis), padded and widened to
/// the plot area's aspect so both axes have one scale.
fn view_range(truth: &[[f64; 2]], map: &[[f64; 2]]) -> [std::ops::Range<f64>; 2] {
    let mut bounds = [[f64::INFINITY, f64::NEG_INFINITY]; 2];
    for axis in 0..2 {
        let mut values: Vec<f64> = map.iter().map(|p| p[axis]).filter(|v| v.is_finite()).collect();
        values.sort_by(f64::total_cmp);
        if !values.is_empty() {
            let at = |q: f64| values[((values.len() - 1) as f64 * q).round() as usize];
            bounds[axis] = [at(0.02), at(0.98)];
        }
        for p in truth.iter().filter(|p| p[axis].is_finite()) {
            bounds[axis] = [bounds[axis][0].min(p[axis]), bounds[axis][1].max(p[axis])];
        }
    }
    let mut range = [padded(bounds[0][0], bounds[0][1], 0.05), padded(bounds[1][0], bounds[1][1], 0.05)];
    let per_pixel = ((range[0].end - range[0].start) / PLOT_AREA.0).max((range[1].end - range[1].start) / PLOT_AREA.1);
    for (axis, pixels) in [PLOT_AREA.0, PLOT_AREA.1].into_iter().enumerate() {
        let (centre, half) = ((range[axis].start + range[axis].end) / 2.0, per_pixel * pixels / 2.0);
        range[axis] = (centre - half)..(centre + half);
    }
    range
}

impl Figure for Trajectory {
    fn size(&self) -> (u32, u32) {
        SIZE
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(root)
            .caption("Trajectory from above", (FONT, 24))
            .margin(15)
            .x_label_area_size(50)
            .y_label_area_size(70)
            .build_cartesian_2d(self.range[0].clone(), self.range[1].clone())?;
        chart
            .configure_mesh()
            .light_line_style(WHITE.mix(0.0))
            .x_desc(format!("map {} (m)", AXIS_NAMES[self.axes[0]]))
            .y_desc(format!("map {} (m)", AXIS_NAMES[self.axes[1]]))
            .label_style((FONT, 14))
            .axis_desc_style((FONT, 16))
            .draw()?;
        let faint = RGBColor(170, 170, 170).mix(0.5);
        chart
            .draw_series(self.map.iter().map(|p| Pixel::new((p[0], p[1]), faint)))?
            .label("map points")
            .legend(move |(x, y)| Rectangle::new([(x + 6, y - 2), (x + 10, y + 2)], RGBColor(170, 170, 170).filled()));
        chart
            .draw_series(LineSeries::new(self.truth.iter().map(|p| (p[0], p[1])), BLACK.stroke_width(2)))?
            .label("ground truth")
            .legend(|(x, y)| PathElement::new([(x, y), (x + 16, y)], BLACK.stroke_width(2)));
        // Later methods' markers are smaller and drawn over the earlier ones', so all show.
        for (i, m) in self.methods.iter().enumerate() {
            self.draw_method(&mut chart, m, 3 + (self.methods.len() - 1 - i) as i32)?;
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font((FONT, 14))
            .draw()?;
        Ok(())
    }
}

impl Trajectory {
    fn draw_method<DB: DrawingBackend>(
        &self,
        chart: &mut ChartContext<
            DB,
            Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
        >,
        m: &MethodPath,
        size: i32,
    ) -> DrawResult<DB> {
        let colour = m.colour;
        let count = |o: Outcome| m.frames.iter().filter(|f| f.outcome == o).count();
        let wrong: Vec<([f64; 2], [f64; 2])> = m
            .frames
            .iter()
            .filter(|f| f.outcome == Outcome::WrongPose)
            .filter_map(|f| Some((f.truth, f.estimate?)))
            .collect();
        chart.draw_series(
            wrong.iter().map(|(t, e)| PathElement::new([(t[0], t[1]), (e[0], e[1])], colour.mix(0.6).stroke_width(1))),
        )?;
        chart
            .draw_series(
                m.frames
                    .iter()
                    .filter(|f| f.outcome == Outcome::Registered)
                    .filter_map(|f| f.estimate)
                    .map(|e| Circle::new((e[0], e[1]), size, colour.filled())),
            )?
            .label(format!("{}: registered ({})", m.label, count(Outcome::Registered)))
            .legend(move |(x, y)| Circle::new((x + 8, y), size, colour.filled()));
        chart
            .draw_series(wrong.iter().map(|(_, e)| Circle::new((e[0], e[1]), size + 1, colour.stroke_width(2))))?
            .label(format!("{}: RMSE over 0.1 m, tied to truth ({})", m.label, count(Outcome::WrongPose)))
            .legend(move |(x, y)| Circle::new((x + 8, y), size + 1, colour.stroke_width(2)));
        chart
            .draw_series(
                m.frames
                    .iter()
                    .filter(|f| f.outcome == Outcome::NoPose)
                    .map(|f| Cross::new((f.truth[0], f.truth[1]), size + 3, colour.stroke_width(2))),
            )?
            .label(format!("{}: no pose, at true position ({})", m.label, count(Outcome::NoPose)))
            .legend(move |(x, y)| Cross::new((x + 8, y), size + 3, colour.stroke_width(2)));
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn view_keeps_the_truth_and_one_scale() {
        let truth = [[0.0, 0.0], [4.0, 1.0]];
        let map: Vec<[f64; 2]> = (0..100).map(|k| [k as f64 / 10.0 - 5.0, 0.5]).chain([[1e6, 1e6]]).collect();
        let [x, y] = view_range(&truth, &map);
        assert!(x.start <= -4.8 && x.end >= 4.8, "{x:?}");
        assert!(x.end < 100.0 && y.end < 100.0, "the far outlier is not in view: {x:?} {y:?}");
        assert!(y.start <= 0.0 && y.end >= 1.0);
        let scale = ((x.end - x.start) / PLOT_AREA.0, (y.end - y.start) / PLOT_AREA.1);
        assert!((scale.0 - scale.1).abs() < 1e-9, "{scale:?}");
    }
}
