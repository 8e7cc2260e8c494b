//! The commands' bag edges: `replay` (bag → localizer → bag) and `evaluate` (input bag with
//! ground truth + output bag → metrics). Geometry stays in the core; this only moves messages.

use std::collections::HashMap;
use std::path::Path;

use anyhow::{Context, Result};
use nalgebra::Isometry3;

use crate::bag::{read_frames, BagFrames, BagReader, BagWriter, TopicMap};
use crate::eval::{inlier_mask, inlier_ratio, pose_errors, summarize, FrameMetrics, Summary};
use crate::frame::{Correspondence, IncompleteFrame, Stamp};
use crate::msgs::{self, convert, from_cdr, DiagnosticArray, DiagnosticStatus, Header, KeyValue};
use crate::pipeline::{Localization, Localizer};

/// Topic of the per-frame diagnostics written by `replay` (timings, method, failure reason).
pub const DIAGNOSTICS_TOPIC: &str = "/diagnostics";
/// Name of the diagnostics status that carries one frame's localization report.
pub const STATUS_NAME: &str = "angle_i2p: localization";

/// What a replay did.
pub struct ReplayReport {
    pub localizations: Vec<Localization>,
    pub incomplete: Vec<IncompleteFrame>,
    pub issues: Vec<String>,
}

/// Runs `localizer` over every frame of the bag at `input` and writes the results to a new bag
/// at `output`. `on_frame` is called after each frame (progress reporting).
pub fn replay(
    input: &Path,
    output: &Path,
    localizer: &mut Localizer,
    topics: &TopicMap,
    mut on_frame: impl FnMut(usize, usize, &Localization),
) -> Result<ReplayReport> {
    let BagFrames { map, frames, incomplete, issues } = read_frames(input, topics)?;
    if let Some(e) = localizer.setup_error() {
        anyhow::bail!("method {}: {e}", localizer.params().method.name());
    }
    if let Some(map) = &map {
        localizer.set_map(map);
    }
    let mut writer = BagWriter::create(output)?;
    let mut localizations = Vec::with_capacity(frames.len());
    for (k, frame) in frames.iter().enumerate() {
        let loc = localizer.process(frame);
        write_localization(&mut writer, topics, &loc)?;
        on_frame(k, frames.len(), &loc);
        localizations.push(loc);
    }
    for missing in &incomplete {
        if missing.dropped {
            write_diagnostics(
                &mut writer,
                missing.stamp,
                localizer.params().method.name(),
                &[],
                Some(&describe(missing)),
            )?;
        }
    }
    writer.finish()?;
    Ok(ReplayReport {
        localizations,
        incomplete,
        issues: issues.iter().map(|i| format!("{}: {}", i.topic, i.reason)).collect(),
    })
}

pub fn describe(f: &IncompleteFrame) -> String {
    let mut parts = Vec::new();
    if !f.missing.is_empty() {
        parts.push(format!("missing {}", f.missing.join(", ")));
    }
    parts.extend(f.errors.iter().cloned());
    format!("frame {}: {}{}", f.stamp, parts.join("; "), if f.dropped { " (skipped)" } else { "" })
}

fn write_localization(w: &mut BagWriter, topics: &TopicMap, loc: &Localization) -> Result<()> {
    let t = loc.stamp;
    if let Some(pose) = &loc.pose {
        w.write(&topics.pose, t, &convert::pose_stamped(t, &loc.map_frame_id, pose))?;
        if let Some(cov) = &loc.covariance {
            w.write(
                &topics.pose_with_covariance,
                t,
                &convert::pose_with_covariance_stamped(t, &loc.map_frame_id, pose, cov),
            )?;
        }
    }
    let kept = convert::correspondences_msg(t, &loc.camera_frame_id, &loc.map_frame_id, &loc.kept);
    w.write(&topics.output_correspondences, t, &kept)?;
    w.write(DIAGNOSTICS_TOPIC, t, &localization_diagnostics(loc))?;
    Ok(())
}

/// The per-frame diagnostics `replay` writes for `loc` (status [`STATUS_NAME`]: method,
/// timings, kept, PnP inliers, failure); `node --record` records the same.
pub fn localization_diagnostics(loc: &Localization) -> DiagnosticArray {
    let t_ = &loc.timings;
    let values = [
        ("total_ms", format!("{:.4}", t_.total_ms)),
        ("geometry_ms", format!("{:.4}", t_.geometry_ms)),
        ("reject_ms", format!("{:.4}", t_.reject_ms)),
        ("pnp_ms", format!("{:.4}", t_.pnp_ms)),
        ("fast_path_ms", format!("{:.4}", t_.fast_path_ms)),
        ("kept", loc.kept.len().to_string()),
        ("pnp_inliers", loc.num_inliers.to_string()),
        ("pnp_iterations", loc.pnp_iterations.to_string()),
        ("fast_path", loc.fast_path.to_string()),
        ("prior_quality", loc.prior_quality.map_or_else(|| "unknown".to_string(), |q| format!("{q:.3}"))),
    ];
    let failure = loc.failure.as_ref().map(|f| f.to_string());
    diagnostics_msg(loc.stamp, loc.method.name(), &values, failure.as_deref())
}

fn write_diagnostics(
    w: &mut BagWriter,
    stamp: Stamp,
    method: &str,
    values: &[(&str, String)],
    failure: Option<&str>,
) -> Result<()> {
    w.write(DIAGNOSTICS_TOPIC, stamp, &diagnostics_msg(stamp, method, values, failure))?;
    Ok(())
}

fn diagnostics_msg(stamp: Stamp, method: &str, values: &[(&str, String)], failure: Option<&str>) -> DiagnosticArray {
    let mut kv = vec![KeyValue { key: "method".into(), value: method.into() }];
    kv.extend(values.iter().map(|(k, v)| KeyValue { key: (*k).into(), value: v.clone() }));
    let status = DiagnosticStatus {
        level: if failure.is_some() { DiagnosticStatus::WARN } else { DiagnosticStatus::OK },
        name: STATUS_NAME.into(),
        message: failure.unwrap_or("localized").into(),
        hardware_id: String::new(),
        values: kv,
    };
    DiagnosticArray { header: Header::new(stamp, ""), status: vec![status] }
}

/// What an output bag says about one frame.
#[derive(Default)]
struct Estimate {
    pose: Option<Isometry3<f64>>,
    kept: Vec<Correspondence>,
    ms: Option<f64>,
}

/// An evaluated output bag.
pub struct Evaluation {
    pub method: String,
    pub summary: Summary,
    pub frames: Vec<FrameMetrics>,
}

/// Scores the output bag `est` against the ground truth of the input bag `input`, frame by
/// frame over the input's frames (a frame with no output counts as not registered).
pub fn evaluate(input: &BagFrames, est: &Path, topics: &TopicMap) -> Result<Evaluation> {
    let reader = BagReader::open(est)?;
    let mut by_stamp: HashMap<Stamp, Estimate> = HashMap::new();
    let mut method = None;
    for m in reader.messages() {
        let topic = m.topic();
        let decode_err = || format!("{}: {topic} at log time {}", est.display(), m.log_time);
        if topic == topics.pose {
            let msg: msgs::PoseStamped = from_cdr(&m.data).with_context(decode_err)?;
            let pose = convert::isometry_from_pose(&msg.pose).with_context(decode_err)?;
            by_stamp.entry(convert::stamp(&msg.header)).or_default().pose = Some(pose);
        } else if topic == topics.output_correspondences {
            let msg: msgs::Correspondences = from_cdr(&m.data).with_context(decode_err)?;
            let kept = convert::correspondences_from_msg(&msg).with_context(decode_err)?;
            by_stamp.entry(convert::stamp(&msg.header)).or_default().kept = kept;
        } else if topic == DIAGNOSTICS_TOPIC {
            let msg: DiagnosticArray = from_cdr(&m.data).with_context(decode_err)?;
            for status in msg.status.iter().filter(|s| s.name == STATUS_NAME) {
                let value = |key: &str| status.values.iter().find(|kv| kv.key == key).map(|kv| kv.value.clone());
                method = method.or_else(|| value("method"));
                if let Some(ms) = value("total_ms").and_then(|v| v.parse().ok()) {
                    by_stamp.entry(convert::stamp(&msg.header)).or_default().ms = Some(ms);
                }
            }
        }
    }
    let mut rows = Vec::new();
    for frame in &input.frames {
        let Some(gt) = &frame.ground_truth else { continue };
        let (Some(gt_pose), Some(gt_depth)) = (&gt.pose, &gt.depth) else { continue };
        let e = by_stamp.remove(&frame.stamp).unwrap_or_default();
        let mask = inlier_mask(&e.kept, &frame.intrinsics, gt_pose, gt_depth);
        rows.push(FrameMetrics {
            stamp: frame.stamp,
            inlier_ratio: inlier_ratio(&mask),
            errors: e.pose.map(|p| pose_errors(&p, gt_pose, &frame.intrinsics, gt_depth)),
            ms: e.ms,
        });
    }
    anyhow::ensure!(!rows.is_empty(), "{}: no frame with ground-truth pose and depth to score against", "input bag");
    Ok(Evaluation {
        method: method.unwrap_or_else(|| est.display().to_string()),
        summary: summarize(&rows),
        frames: rows,
    })
}

/// The inlier ratio of the matcher's raw correspondences (the input's IR).
pub fn raw_inlier_ratio(input: &BagFrames) -> Summary {
    let rows: Vec<FrameMetrics> = input
        .frames
        .iter()
        .filter_map(|f| {
            let gt = f.ground_truth.as_ref()?;
            let (pose, depth) = (gt.pose.as_ref()?, gt.depth.as_ref()?);
            let mask = inlier_mask(&f.correspondences, &f.intrinsics, pose, depth);
            Some(FrameMetrics { stamp: f.stamp, inlier_ratio: inlier_ratio(&mask), errors: None, ms: None })
        })
        .collect();
    summarize(&rows)
}

/// What an export wrote.
pub struct ExportReport {
    pub samples: usize,
    pub skipped: Vec<String>,
}

/// Writes one training sample per frame of `input` that has ground truth: a folder per stamp
/// with `.npy` arrays — `features` (N×24, eq. 9), `local_index` (V×K), `local_theta` (V×K×K),
/// `global_index` (M), `global_theta` (M×M), `cross_theta` (N×M), `spectral` (N), `labels` (N:
/// 1 inlier, 0 outlier, −1 no ground-truth depth; the 5 cm rule of `eval`) and `correspondences`
/// (N×6: u, v, x, y, z, score).
pub fn export_samples(input: &Path, out: &Path, params: &crate::params::Params) -> Result<ExportReport> {
    use crate::npy;
    use crate::reject::inputs::{build_inputs, IndexedMap};
    use crate::reject::{FrameGeometry, SpectralRejector};

    let bag = read_frames(input, &params.topics)?;
    let map = bag.map.as_ref().map(|m| IndexedMap::new(m.points.clone()));
    let mut spectral = SpectralRejector::new(params.network.keypoint_spectral(params.spectral.clone()));
    let mut report = ExportReport { samples: 0, skipped: Vec::new() };
    for frame in &bag.frames {
        let Some((gt_pose, gt_depth)) =
            frame.ground_truth.as_ref().and_then(|g| Some((g.pose.as_ref()?, g.depth.as_ref()?)))
        else {
            report.skipped.push(format!("frame {}: no ground-truth pose and depth", frame.stamp));
            continue;
        };
        if frame.depth_prior.is_none() || frame.correspondences.is_empty() {
            report.skipped.push(format!("frame {}: no depth prior or no correspondences", frame.stamp));
            continue;
        }
        let geometry = FrameGeometry::build(frame, params.depth_kind, params.network.alignment(&params.align));
        let inputs = build_inputs(&geometry, map.as_ref(), &mut spectral, &params.network);
        let labels: Vec<f32> = inlier_mask(&frame.correspondences, &frame.intrinsics, gt_pose, gt_depth)
            .into_iter()
            .map(|(inlier, valid)| {
                if !valid {
                    -1.0
                } else if inlier {
                    1.0
                } else {
                    0.0
                }
            })
            .collect();
        let dir = out.join(frame.stamp.to_string());
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        let (n, g) = (geometry.len(), &inputs.graphs);
        let m = g.global_index.len();
        let index = |v: &[u32]| v.iter().map(|&i| i as i64).collect::<Vec<i64>>();
        let flat: Vec<f32> = inputs.features.iter().flatten().copied().collect();
        let corr: Vec<f32> = frame
            .correspondences
            .iter()
            .flat_map(|c| {
                [c.pixel.x as f32, c.pixel.y as f32, c.point.x as f32, c.point.y as f32, c.point.z as f32, c.score]
            })
            .collect();
        let write =
            |name: &str, r: std::io::Result<()>| r.with_context(|| format!("writing {}/{name}.npy", dir.display()));
        write("features", npy::write(&dir.join("features.npy"), &flat, &[n, flat.len() / n.max(1)]))?;
        write(
            "local_index",
            npy::write(&dir.join("local_index.npy"), &index(&g.local_index), &[g.nodes, g.neighbours]),
        )?;
        write(
            "local_theta",
            npy::write(&dir.join("local_theta.npy"), &g.local_theta, &[g.nodes, g.neighbours, g.neighbours]),
        )?;
        write("global_index", npy::write(&dir.join("global_index.npy"), &index(&g.global_index), &[m]))?;
        write("global_theta", npy::write(&dir.join("global_theta.npy"), &g.global_theta, &[m, m]))?;
        write("cross_theta", npy::write(&dir.join("cross_theta.npy"), &g.cross_theta, &[n, m]))?;
        write("spectral", npy::write(&dir.join("spectral.npy"), &inputs.spectral_scores, &[n]))?;
        write("labels", npy::write(&dir.join("labels.npy"), &labels, &[n]))?;
        write("correspondences", npy::write(&dir.join("correspondences.npy"), &corr, &[n, 6]))?;
        report.samples += 1;
    }
    Ok(report)
}
