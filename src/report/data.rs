//! What the report knows per frame and method: the scores `eval` computed, and what the output
//! bag says beyond the pose — kept correspondences and the `/diagnostics` status `replay` (or
//! `node --record`) wrote: stage timings, kept and PnP inlier counts, failure reason, and the
//! prior's quality when a run reports one.

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::Isometry3;

use super::{ReportError, ReportInput};
use crate::app::{DIAGNOSTICS_TOPIC, STATUS_NAME};
use crate::bag::{BagReader, TopicMap};
use crate::eval::{inlier_mask, FrameMetrics, Summary};
use crate::frame::{Correspondence, Stamp};
use crate::msgs::{self, convert, from_cdr, DiagnosticArray, DiagnosticStatus};

/// One frame of an output bag.
#[derive(Clone, Debug, Default)]
pub struct FrameRecord {
    pub pose: Option<Isometry3<f64>>,
    pub kept: Vec<Correspondence>,
    pub stages: Option<StageMs>,
    pub kept_count: Option<usize>,
    pub pnp_inliers: Option<usize>,
    /// `prior_quality` of the diagnostics, when the run reports it.
    pub prior_quality: Option<f64>,
    /// The diagnostics' message when the status is not OK (why the frame has no pose).
    pub failure: Option<String>,
}

/// Per-stage wall time of one frame (ms).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageMs {
    pub geometry: f64,
    pub reject: f64,
    pub pnp: f64,
    pub total: f64,
}

/// Everything an output bag says, by frame stamp.
#[derive(Debug, Default)]
pub struct RunRecords {
    pub by_stamp: BTreeMap<Stamp, FrameRecord>,
}

/// Reads the poses, kept correspondences and diagnostics of the output bag at `est`.
pub fn read_run_records(est: &Path, topics: &TopicMap) -> Result<RunRecords, ReportError> {
    let fail = |message: String| ReportError::ReadRun { path: est.to_path_buf(), message };
    let reader = BagReader::open(est).map_err(|e| fail(e.to_string()))?;
    let mut records = RunRecords::default();
    for m in reader.messages() {
        let topic = m.topic();
        let at = |e: &dyn std::fmt::Display| fail(format!("{topic} at log time {}: {e}", m.log_time));
        if topic == topics.pose {
            let msg: msgs::PoseStamped = from_cdr(&m.data).map_err(|e| at(&e))?;
            let pose = convert::isometry_from_pose(&msg.pose).map_err(|e| at(&e))?;
            records.by_stamp.entry(convert::stamp(&msg.header)).or_default().pose = Some(pose);
        } else if topic == topics.output_correspondences {
            let msg: msgs::Correspondences = from_cdr(&m.data).map_err(|e| at(&e))?;
            let kept = convert::correspondences_from_msg(&msg).map_err(|e| at(&e))?;
            records.by_stamp.entry(convert::stamp(&msg.header)).or_default().kept = kept;
        } else if topic == DIAGNOSTICS_TOPIC {
            let msg: DiagnosticArray = from_cdr(&m.data).map_err(|e| at(&e))?;
            let stamp = convert::stamp(&msg.header);
            for status in msg.status.iter().filter(|s| s.name == STATUS_NAME) {
                apply_status(records.by_stamp.entry(stamp).or_default(), status);
            }
        }
    }
    Ok(records)
}

fn apply_status(record: &mut FrameRecord, status: &DiagnosticStatus) {
    let number = |key: &str| -> Option<f64> {
        status.values.iter().find(|kv| kv.key == key).and_then(|kv| kv.value.trim().parse().ok())
    };
    let stage = |key: &str| number(key).filter(|v| v.is_finite() && *v >= 0.0);
    if let Some(total) = stage("total_ms") {
        record.stages = Some(StageMs {
            geometry: stage("geometry_ms").unwrap_or(0.0),
            reject: stage("reject_ms").unwrap_or(0.0),
            pnp: stage("pnp_ms").unwrap_or(0.0),
            total,
        });
    }
    let count = |key: &str| number(key).filter(|v| *v >= 0.0 && v.fract() == 0.0).map(|v| v as usize);
    record.kept_count = count("kept").or(record.kept_count);
    record.pnp_inliers = count("pnp_inliers").or(record.pnp_inliers);
    record.prior_quality = number("prior_quality").filter(|v| v.is_finite()).or(record.prior_quality);
    if status.level != DiagnosticStatus::OK {
        record.failure = Some(status.message.clone());
    }
}

/// How a frame ended for a method.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// A pose within the RR threshold.
    Registered,
    /// A pose, but its RMSE is over the RR threshold.
    WrongPose,
    NoPose,
}

/// One evaluated frame of one method.
#[derive(Clone, Debug)]
pub struct ScoredFrame {
    /// Index of the frame in the input bag's frames.
    pub frame_index: usize,
    pub metrics: FrameMetrics,
    pub record: FrameRecord,
    /// Kept correspondences that are true inliers (the IR's 5 cm rule).
    pub true_inliers_kept: usize,
}

impl ScoredFrame {
    pub fn outcome(&self) -> Outcome {
        match self.metrics.errors {
            None => Outcome::NoPose,
            Some(_) if self.metrics.registered() => Outcome::Registered,
            Some(_) => Outcome::WrongPose,
        }
    }

    /// RMSE used to rank frames; a frame without a pose ranks worst.
    pub fn rank_error(&self) -> f64 {
        self.metrics.errors.map_or(f64::INFINITY, |e| if e.rmse_m.is_finite() { e.rmse_m } else { f64::INFINITY })
    }
}

/// One method's frames, in input order.
pub struct ScoredRun {
    pub label: String,
    pub summary: Summary,
    pub frames: Vec<ScoredFrame>,
    /// Failures the output bag reports for frames that were not scored (skipped by replay).
    pub unscored_failures: Vec<(Stamp, String)>,
}

/// All methods' frames.
pub struct ScoredRuns {
    pub runs: Vec<ScoredRun>,
    /// Input-frame indices of the scored frames (those with ground-truth pose and depth).
    pub frame_indices: Vec<usize>,
}

impl ScoredRuns {
    pub fn build(input: &ReportInput) -> Result<Self, ReportError> {
        let frame_indices: Vec<usize> = input
            .bag
            .frames
            .iter()
            .enumerate()
            .filter(|(_, f)| f.ground_truth.as_ref().is_some_and(|g| g.pose.is_some() && g.depth.is_some()))
            .map(|(k, _)| k)
            .collect();
        if frame_indices.is_empty() {
            return Err(ReportError::NoFrames);
        }
        let mut runs = Vec::with_capacity(input.runs.len());
        for run in &input.runs {
            let mut records = read_run_records(&run.est, input.topics)?;
            let by_stamp: BTreeMap<Stamp, &FrameMetrics> = run.evaluation.frames.iter().map(|m| (m.stamp, m)).collect();
            let mut frames = Vec::with_capacity(frame_indices.len());
            for &k in &frame_indices {
                let frame = &input.bag.frames[k];
                let metrics = by_stamp.get(&frame.stamp).map_or_else(
                    || FrameMetrics { stamp: frame.stamp, inlier_ratio: 0.0, errors: None, ms: None },
                    |m| (*m).clone(),
                );
                let record = records.by_stamp.remove(&frame.stamp).unwrap_or_default();
                let true_inliers_kept = match frame.ground_truth.as_ref() {
                    Some(gt) => match (&gt.pose, &gt.depth) {
                        (Some(pose), Some(depth)) => inlier_mask(&record.kept, &frame.intrinsics, pose, depth)
                            .iter()
                            .filter(|(inlier, valid)| *inlier && *valid)
                            .count(),
                        _ => 0,
                    },
                    None => 0,
                };
                frames.push(ScoredFrame { frame_index: k, metrics, record, true_inliers_kept });
            }
            let unscored_failures =
                records.by_stamp.into_iter().filter_map(|(stamp, r)| r.failure.map(|f| (stamp, f))).collect();
            runs.push(ScoredRun {
                label: run.label.clone(),
                summary: run.evaluation.summary.clone(),
                frames,
                unscored_failures,
            });
        }
        Ok(ScoredRuns { runs, frame_indices })
    }
}

/// A failure reason with its numbers replaced by `#`, so reasons of one kind count together.
pub fn reason_kind(reason: &str) -> String {
    let mut out = String::with_capacity(reason.len());
    let mut in_number = false;
    for c in reason.chars() {
        let numeric = c.is_ascii_digit() || (in_number && c == '.');
        if numeric {
            if !in_number {
                out.push('#');
            }
        } else {
            out.push(c);
        }
        in_number = numeric;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::KeyValue;

    fn status(level: u8, message: &str, values: &[(&str, &str)]) -> DiagnosticStatus {
        DiagnosticStatus {
            level,
            name: STATUS_NAME.into(),
            message: message.into(),
            hardware_id: String::new(),
            values: values.iter().map(|(k, v)| KeyValue { key: (*k).into(), value: (*v).into() }).collect(),
        }
    }

    #[test]
    fn diagnostics_fill_the_record() {
        let mut r = FrameRecord::default();
        let values = [
            ("total_ms", "3.5"),
            ("geometry_ms", "1"),
            ("reject_ms", "0.5"),
            ("pnp_ms", "2"),
            ("kept", "40"),
            ("pnp_inliers", "12"),
            ("prior_quality", "0.8"),
        ];
        apply_status(&mut r, &status(DiagnosticStatus::OK, "localized", &values));
        assert_eq!(r.stages, Some(StageMs { geometry: 1.0, reject: 0.5, pnp: 2.0, total: 3.5 }));
        assert_eq!((r.kept_count, r.pnp_inliers, r.prior_quality), (Some(40), Some(12), Some(0.8)));
        assert_eq!(r.failure, None);
        let mut bad = FrameRecord::default();
        let junk = [("total_ms", "-1"), ("kept", "2.5"), ("prior_quality", "nan")];
        apply_status(&mut bad, &status(DiagnosticStatus::WARN, "PnP failed: 3 < 6", &junk));
        assert_eq!((bad.stages, bad.kept_count, bad.prior_quality), (None, None, None));
        assert_eq!(bad.failure.as_deref(), Some("PnP failed: 3 < 6"));
    }

    #[test]
    fn reasons_of_one_kind_share_a_key() {
        assert_eq!(reason_kind("too few correspondences: 3 < 6"), "too few correspondences: # < #");
        assert_eq!(reason_kind("frame 17000: missing x (0.25 s)"), "frame #: missing x (# s)");
        assert_eq!(reason_kind("PnP failed: 3 < 6"), reason_kind("PnP failed: 12 < 60"));
    }
}
