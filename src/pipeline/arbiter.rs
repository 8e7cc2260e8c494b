//! The last choice among the rejection-guided PnP's candidates, on every correspondence of the
//! frame: rejection keeps a subset so that sampling is fast, and on it two poses can explain
//! about as much (a pose and its mirror across a plane that holds most of the kept true matches,
//! as at close range; a wrong cluster the weak prior prefers); the matches rejection left out
//! tell them apart.

use nalgebra::Isometry3;

use crate::frame::Correspondence;
use crate::geometry::Intrinsics;

/// How much of a frame's correspondences a pose explains.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Support {
    /// Correspondences within the inlier threshold.
    pub inliers: usize,
    /// Distinct image cells holding one.
    pub cells: usize,
    /// MSAC cost: the squared reprojection error, capped at the threshold's square, summed.
    pub msac: f64,
}

impl Support {
    /// Whether this support is more than `other`'s: more cells, or as many and more inliers.
    pub fn exceeds(&self, other: &Support) -> bool {
        (self.cells, self.inliers) > (other.cells, other.inliers)
    }
}

/// The share of the incumbent's inliers a candidate keeps to be the same answer, sharpened.
const SAME_ANSWER_SHARE: f64 = 0.9;

/// A candidate of the last choice: its support, and how many of the incumbent's inliers are
/// its inliers too.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Challenge {
    pub support: Support,
    pub shared: usize,
}

impl Challenge {
    /// Whether it may replace the `incumbent`. One that keeps nine in ten of the incumbent's
    /// inliers is the same answer next to it (PnP's pose on the kept set can settle in a wrong
    /// basin of the reprojection error a degree off): it replaces it when it fits every match
    /// better (MSAC) and explains at least as many. Another answer must cover more than `margin`
    /// times the incumbent's cells (PnP's choice, verified against the prior, is not overturned
    /// by a wrong cluster that explains about as much).
    pub fn beats(&self, incumbent: &Support, margin: f64) -> bool {
        if self.shared as f64 >= SAME_ANSWER_SHARE * incumbent.inliers as f64 {
            self.support.msac < incumbent.msac && !incumbent.exceeds(&self.support)
        } else {
            self.support.cells as f64 > margin * incumbent.cells as f64
        }
    }
}

/// The last choice: of the `candidates` that beat the `incumbent` ([`Challenge::beats`]), the
/// best supported; `None`: the incumbent stays. The most support wins, not the first candidate
/// past the bar (two can land near each other, one of them in a wrong basin).
pub fn challenger<T>(
    incumbent: Support,
    candidates: impl IntoIterator<Item = (Challenge, T)>,
    margin: f64,
) -> Option<T> {
    let mut best: Option<(Support, T)> = None;
    for (challenge, candidate) in candidates.into_iter().filter(|(c, _)| c.beats(&incumbent, margin)) {
        if best.as_ref().is_none_or(|(most, _)| challenge.support.exceeds(most)) {
            best = Some((challenge.support, candidate));
        }
    }
    best.map(|(_, candidate)| candidate)
}

/// The [`Support`] of the camera-to-map `pose` among `correspondences`: reprojection error
/// under `threshold_px`, cells `cell_px` wide (at least one pixel) over the image of `k` (pixels
/// outside it count in its border cells); and which of them are inliers.
pub fn support(
    k: &Intrinsics,
    correspondences: &[Correspondence],
    pose: &Isometry3<f64>,
    threshold_px: f64,
    cell_px: f64,
) -> (Support, Vec<bool>) {
    let to_cam = pose.inverse();
    let grid = CellGrid::new(k, cell_px);
    let cap = threshold_px * threshold_px;
    let mut cells: Vec<usize> = Vec::new();
    let mut flags = Vec::with_capacity(correspondences.len());
    let mut msac = 0.0;
    for c in correspondences {
        let error = k.reprojection_error(&to_cam.transform_point(&c.point), &c.pixel);
        let inlier = error < threshold_px;
        if inlier {
            cells.push(grid.cell(&c.pixel));
        }
        msac += (error * error).min(cap);
        flags.push(inlier);
    }
    let inliers = cells.len();
    cells.sort_unstable();
    cells.dedup();
    (Support { inliers, cells: cells.len(), msac }, flags)
}

/// Square image cells `cell_px` wide (at least one pixel) over the image of `k`; pixels outside
/// it count in its border cells.
#[derive(Clone, Copy, Debug)]
pub struct CellGrid {
    cell_px: f64,
    cols: usize,
    rows: usize,
}

impl CellGrid {
    pub fn new(k: &Intrinsics, cell_px: f64) -> Self {
        let cell_px = cell_px.max(1.0);
        let cols = (k.width as f64 / cell_px).ceil().max(1.0) as usize;
        let rows = (k.height as f64 / cell_px).ceil().max(1.0) as usize;
        Self { cell_px, cols, rows }
    }

    /// The cell holding `pixel`, numbered row by row.
    pub fn cell(&self, pixel: &nalgebra::Point2<f64>) -> usize {
        let col = ((pixel.x.max(0.0) / self.cell_px) as usize).min(self.cols - 1);
        let row = ((pixel.y.max(0.0) / self.cell_px) as usize).min(self.rows - 1);
        row * self.cols + col
    }

    /// Distinct cells holding one of `pixels`.
    pub fn occupied<'a>(&self, pixels: impl Iterator<Item = &'a nalgebra::Point2<f64>>) -> usize {
        let mut cells: Vec<usize> = pixels.map(|p| self.cell(p)).collect();
        cells.sort_unstable();
        cells.dedup();
        cells.len()
    }
}

/// How many correspondences both flag sets hold as inliers.
pub fn shared_inliers(a: &[bool], b: &[bool]) -> usize {
    a.iter().zip(b).filter(|(&x, &y)| x && y).count()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point2, Point3, Translation3, UnitQuaternion};

    /// Inliers within the threshold; cells count distinct ones, border cells catch the pixels
    /// outside the image; a point behind the camera never agrees.
    #[test]
    fn support_counts_inliers_and_their_cells() {
        let k = Intrinsics { fx: 500.0, fy: 500.0, cx: 320.0, cy: 240.0, width: 640, height: 480 };
        let pose =
            Isometry3::from_parts(Translation3::new(0.1, 0.0, -0.2), UnitQuaternion::from_euler_angles(0.0, 0.1, 0.0));
        let at =
            |u: f64, v: f64, offset: f64| (Point2::new(u + offset, v), pose * k.back_project(&Point2::new(u, v), 2.0));
        let pairs = [
            at(10.0, 10.0, 0.0),
            at(20.0, 12.0, 1.0),   // same 32 px cell
            at(300.0, 200.0, 7.9), // just inside 8 px
            at(400.0, 200.0, 8.1), // just outside
            at(639.0, 479.0, 0.0),
            (Point2::new(900.0, 900.0), pose * k.back_project(&Point2::new(900.0, 900.0), 2.0)), // off the image
            (Point2::new(100.0, 100.0), pose * Point3::new(0.0, 0.0, -3.0)),                     // behind
        ];
        let correspondences: Vec<Correspondence> =
            pairs.into_iter().map(|(pixel, point)| Correspondence { pixel, point, score: 1.0 }).collect();
        let (s, flags) = support(&k, &correspondences, &pose, 8.0, 32.0);
        // Cells: the first two share one, the third, and the last one with the pixel off the image.
        assert_eq!((s.inliers, s.cells), (5, 3));
        assert_eq!(flags, [true, true, true, false, true, true, false]);
    }

    /// The best supported candidate wins, not the first past the bar; another answer must pass
    /// the margin, the same answer next to the incumbent must fit every match better; none past
    /// the bar: the incumbent stays. (Building frames: PnP's pose on the kept set explained 5
    /// cells, the fast path's pose 37, in a wrong basin 4° off, and the ranked search's 38, the
    /// truth; and PnP's pose in a wrong basin 1° off, 68 inliers in 37 cells, the ranked search's
    /// 73 in 40 sharing 65 of them.)
    #[test]
    fn the_last_choice_takes_the_best_supported_candidate_past_the_bar() {
        let support = |cells: usize, inliers: usize, msac: f64| Support { inliers, cells, msac };
        let other = |cells, inliers| Challenge { support: support(cells, inliers, 0.0), shared: 0 };
        let incumbent = support(5, 10, 1e4);
        let candidates = [(other(4, 8), "junk"), (other(37, 65), "wrong basin"), (other(38, 67), "truth")];
        assert_eq!(challenger(incumbent, candidates, 1.25), Some("truth"));
        let tied = [(other(37, 65), "fewer inliers"), (other(37, 67), "more inliers")];
        assert_eq!(challenger(incumbent, tied, 1.25), Some("more inliers"));
        let near = support(37, 68, 2.0e4);
        assert_eq!(challenger(near, [(other(38, 67), "another answer")], 1.25), None);
        let same = |support, shared| Challenge { support, shared };
        let sharper = same(support(40, 73, 1.9e4), 65);
        assert_eq!(challenger(near, [(sharper, "sharper")], 1.25), Some("sharper"));
        let looser = same(support(38, 69, 2.1e4), 66);
        assert_eq!(challenger(near, [(looser, "fits worse")], 1.25), None);
        assert_eq!(challenger(incumbent, std::iter::empty::<(Challenge, &str)>(), 1.25), None);
    }
}
