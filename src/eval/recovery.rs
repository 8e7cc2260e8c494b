//! Recovery after a jump (#35): a kidnapped camera — one that moved between two frames far more
//! than the sequence otherwise moves — and how many frames a method takes to publish a correct
//! pose again, with the wrong poses it publishes meanwhile.

use nalgebra::Isometry3;
use serde::Serialize;

use super::FrameMetrics;

/// A step of the ground truth is a jump when it is this many times the sequence's 90th
/// percentile step (in rotation or in translation): a camera that moves smoothly never makes
/// one, at any frame rate or scale.
pub const JUMP_FACTOR: f64 = 5.0;
/// Steps a sequence needs before its percentile says what a jump is.
const MIN_STEPS: usize = 4;

/// How a method came back after the jumps of a sequence.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct Recovery {
    /// Jumps of the ground truth.
    pub jumps: usize,
    /// Most frames from a jump to the first correct published pose (0: the first frame after
    /// the jump is correct); `None` without a recovered jump.
    pub frames_to_recover_max: Option<usize>,
    /// Jumps after which no correct pose was published before the next jump or the end.
    pub unrecovered: usize,
    /// Wrong poses published between a jump and the recovery.
    pub wrong_while_recovering: usize,
}

/// The stamps of the first frames after each jump of the ground-truth `track` (camera-to-map
/// poses in stamp order).
pub fn jumps(track: &[(i64, Isometry3<f64>)]) -> Vec<i64> {
    let steps: Vec<(f64, f64, i64)> = track
        .windows(2)
        .map(|w| {
            let (a, b) = (&w[0].1, &w[1].1);
            (a.rotation.angle_to(&b.rotation), (a.translation.vector - b.translation.vector).norm(), w[1].0)
        })
        .collect();
    if steps.len() < MIN_STEPS {
        return Vec::new();
    }
    let rotation_bar = JUMP_FACTOR * percentile_90(steps.iter().map(|s| s.0));
    let translation_bar = JUMP_FACTOR * percentile_90(steps.iter().map(|s| s.1));
    steps
        .iter()
        .filter(|&&(r, t, _)| {
            (rotation_bar > 0.0 && r > rotation_bar) || (translation_bar > 0.0 && t > translation_bar)
        })
        .map(|&(_, _, stamp)| stamp)
        .collect()
}

/// How the method whose frames are `rows` (in stamp order) recovered after the `jumps`.
pub fn recovery(rows: &[FrameMetrics], jumps: &[i64]) -> Recovery {
    let starts: Vec<usize> = jumps.iter().filter_map(|j| rows.iter().position(|r| r.stamp == *j)).collect();
    let mut out = Recovery { jumps: starts.len(), ..Recovery::default() };
    for (n, &start) in starts.iter().enumerate() {
        let end = starts.get(n + 1).copied().unwrap_or(rows.len());
        let segment = rows.get(start..end).unwrap_or_default();
        let recovered = segment.iter().position(FrameMetrics::registered);
        let before = &segment[..recovered.unwrap_or(segment.len())];
        out.wrong_while_recovering += before.iter().filter(|r| r.errors.is_some()).count();
        match recovered {
            Some(frames) => out.frames_to_recover_max = Some(out.frames_to_recover_max.unwrap_or(0).max(frames)),
            None => out.unrecovered += 1,
        }
    }
    out
}

fn percentile_90(values: impl Iterator<Item = f64>) -> f64 {
    let mut v: Vec<f64> = values.filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * 0.9).round() as usize]
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector3;

    use super::*;
    use crate::eval::PoseErrors;

    fn at(x: f64) -> Isometry3<f64> {
        Isometry3::translation(x, 0.0, 0.0)
    }

    fn row(stamp: i64, rmse_m: Option<f64>) -> FrameMetrics {
        let errors = rmse_m.map(|rmse_m| PoseErrors { rotation_deg: 0.0, translation_m: 0.0, rmse_m, nees: None });
        FrameMetrics { stamp, inlier_ratio: 0.0, errors, ms: None }
    }

    #[test]
    fn a_smooth_track_has_no_jump_and_a_kidnap_is_one() {
        let smooth: Vec<_> = (0..20).map(|k| (k, at(0.05 * k as f64))).collect();
        assert!(jumps(&smooth).is_empty());
        let mut kidnapped = smooth.clone();
        for (k, pose) in kidnapped.iter_mut().skip(10) {
            *pose = at(3.0 + 0.05 * *k as f64) * Isometry3::rotation(Vector3::new(0.0, 3.0, 0.0));
        }
        assert_eq!(jumps(&kidnapped), vec![10]);
        assert!(jumps(&kidnapped[..4]).is_empty(), "too short to say");
    }

    #[test]
    fn recovery_counts_the_frames_to_a_correct_pose_and_the_wrong_ones_before() {
        // Frame 10 jumps: 10 has no pose, 11 a wrong one, 12 is correct; frame 16 jumps and
        // nothing after it is correct.
        let rows: Vec<_> = (0..20)
            .map(|k| match k {
                10 | 16 | 18 => row(k, None),
                11 | 17 => row(k, Some(0.5)),
                _ => row(k, Some(0.01)),
            })
            .map(|mut r| {
                if r.stamp == 19 {
                    r.errors = Some(PoseErrors { rotation_deg: 9.0, translation_m: 1.0, rmse_m: 0.7, nees: None });
                }
                r
            })
            .collect();
        let r = recovery(&rows, &[10, 16]);
        assert_eq!(r, Recovery { jumps: 2, frames_to_recover_max: Some(2), unrecovered: 1, wrong_while_recovering: 3 });
        assert_eq!(recovery(&rows, &[]), Recovery::default());
    }
}
