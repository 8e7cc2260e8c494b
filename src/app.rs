//! The commands' bag edges: `replay` (bag → localizer → bag) and `evaluate` (input bag with
//! ground truth + output bag → metrics). Geometry stays in the core; this only moves messages.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use anyhow::{Context, Result};
use nalgebra::Isometry3;

use crate::bag::{BagFrames, BagMessages, BagWriter, FrameStream, OdometryTopics, ReadOptions, TopicMap};
use crate::camera::CameraModel;
use crate::eval::{
    inlier_mask, inlier_ratio, jumps, nees, pose_errors, recovery, summarize, FrameMetrics, PoseErrors, Recovery,
    Summary,
};
use crate::frame::{Assembled, Correspondence, IncompleteFrame, Stamp};
use crate::limits::InputLimits;
use crate::msgs::{self, convert, from_cdr, DiagnosticArray, DiagnosticStatus, Header, KeyValue};
use crate::params::AppParams;
use crate::pipeline::{Localization, Localizer};

/// Topic of the per-frame diagnostics written by `replay` (timings, method, failure reason).
pub const DIAGNOSTICS_TOPIC: &str = "/diagnostics";
/// Name of the diagnostics status that carries one frame's localization report.
pub const STATUS_NAME: &str = "angle_i2p: localization";

/// How a command reads and writes bags: the topic names and the input limits.
#[derive(Clone, Debug)]
pub struct BagEdge<'a> {
    pub topics: &'a TopicMap,
    pub limits: &'a InputLimits,
    pub pixels: crate::camera::PixelSpace,
    /// Where the robot's odometry is in a bag (`/tf`, `/tf_static` under the command's remaps,
    /// `node.odom_frame`): frames get theirs for tracking.
    pub odometry: OdometryTopics,
}

impl<'a> BagEdge<'a> {
    /// The bag edge of resolved parameters.
    pub fn of(params: &'a AppParams) -> Self {
        Self {
            topics: &params.topics,
            limits: &params.limits,
            pixels: params.camera.pixels,
            odometry: OdometryTopics::of(&params.topics, &params.node),
        }
    }
}

/// What a replay did.
pub struct ReplayReport {
    /// One per frame processed, in processing order; `kept` is emptied once written, so the
    /// report stays small however long the bag.
    pub localizations: Vec<Localization>,
    /// Frames with a missing or broken part, a limit hit, a late part or a repeated stamp.
    pub incomplete: Vec<IncompleteFrame>,
    pub issues: Vec<String>,
}

/// What `replay` tells its caller after each frame.
pub struct FrameProgress<'a> {
    /// 0-based index of the frame, and how many frames the bag holds (its correspondences
    /// messages; at least `index + 1`).
    pub index: usize,
    pub expected: usize,
    pub localization: &'a Localization,
    /// Whether the frame registered (RMSE under 0.1 m, as `eval`), when the bag carries its
    /// ground-truth pose and depth.
    pub registered: Option<bool>,
}

/// Whether `loc` registers `frame` (`None` without ground truth).
fn registered(frame: &crate::frame::Frame, loc: &Localization) -> Option<bool> {
    let gt = frame.ground_truth.as_ref()?;
    let (pose, depth) = (gt.pose.as_ref()?, gt.depth.as_ref()?);
    Some(loc.pose.as_ref().is_some_and(|p| pose_errors(p, pose, &frame.intrinsics, depth).registered()))
}

/// Makes the calling thread one of rayon's (the global pool's first): a frame's parallel parts
/// then run on the thread that localizes it and are shared with the other threads as they are
/// free, instead of that thread waiting for a pool thread to wake at every parallel step (on a
/// 2-vCPU VM: synthetic hard+harsh 10.2 → 8.5 ms per frame). Once per process, before any other
/// rayon use; later calls do nothing.
pub fn work_on_this_thread() {
    // An error only means the global pool exists already (then frames run as before).
    let _ = rayon::ThreadPoolBuilder::new().use_current_thread().build_global();
}

/// Runs `localizer` over every frame of the bag at `input` and writes the results to a new bag
/// at `output`, frame by frame as they are read (memory does not grow with the bag's length).
/// The bag is checked whole before the output is created; the map is used wherever it is in
/// the bag. A frame that cannot be processed is skipped with its reason (in `/diagnostics` and
/// the report). `on_frame` is called after each frame ([`FrameProgress`]).
pub fn replay(
    input: &Path,
    output: &Path,
    localizer: &mut Localizer,
    edge: BagEdge,
    mut on_frame: impl FnMut(&FrameProgress),
) -> Result<ReplayReport> {
    let topics = edge.topics;
    let mut stream =
        FrameStream::open(input, topics, edge.limits)?.with_pixel_space(edge.pixels).with_odometry(edge.odometry);
    if let Some(map) = stream.map.take() {
        localizer.set_map(&map);
    }
    let expected = stream.correspondence_messages;
    let mut writer = BagWriter::create(output)?;
    let mut report = ReplayReport { localizations: Vec::new(), incomplete: Vec::new(), issues: Vec::new() };
    while let Some(item) = stream.next_frame()? {
        let mut frame = match item {
            Assembled::Complete(f) => f,
            Assembled::Partial(f, r) => {
                report.incomplete.push(r);
                f
            }
            Assembled::Dropped(r) => {
                let method = localizer.params().method.name();
                write_diagnostics(&mut writer, r.stamp, method, &[], Some(&describe(&r)))?;
                report.incomplete.push(r);
                continue;
            }
        };
        let mut loc = localizer.process(&frame);
        let registered = registered(&frame, &loc);
        let lens = frame.lens.take();
        drop(frame);
        write_localization(&mut writer, topics, &loc, lens.as_ref())?;
        let index = report.localizations.len();
        on_frame(&FrameProgress { index, expected: expected.max(index + 1), localization: &loc, registered });
        loc.kept = Vec::new();
        report.localizations.push(loc);
    }
    writer.finish()?;
    report.issues = stream.issues.iter().map(|i| format!("{}: {}", i.topic, i.reason)).collect();
    report.issues.extend(stream.limit_counts.summary());
    if let Some(odometry) = stream.odometry.as_ref().filter(|o| o.left_out > 0) {
        report.issues.extend(odometry.issues.iter().map(|i| format!("tf: {i}")));
        report.issues.push(format!("tf: {} transforms or messages left out in all", odometry.left_out));
    }
    Ok(report)
}

pub fn describe(f: &IncompleteFrame) -> String {
    let mut parts = Vec::new();
    if !f.missing.is_empty() {
        parts.push(format!("missing {}", f.missing.join(", ")));
    }
    parts.extend(f.errors.iter().cloned());
    format!("frame {}: {}{}", f.stamp, parts.join("; "), if f.dropped { " (skipped)" } else { "" })
}

fn write_localization(
    w: &mut BagWriter,
    topics: &TopicMap,
    loc: &Localization,
    lens: Option<&CameraModel>,
) -> Result<()> {
    let t = loc.stamp;
    let out = convert::localization_messages(loc, lens);
    if let Some(pose) = &out.pose {
        w.write(&topics.pose, t, pose)?;
    }
    if let Some(pose_with_covariance) = &out.pose_with_covariance {
        w.write(&topics.pose_with_covariance, t, pose_with_covariance)?;
    }
    w.write(&topics.output_correspondences, t, &out.kept)?;
    w.write(DIAGNOSTICS_TOPIC, t, &localization_diagnostics(loc))?;
    Ok(())
}

/// The per-frame diagnostics `replay` writes for `loc` (status [`STATUS_NAME`]: method,
/// timings, kept, PnP inliers, failure); `node --record` records the same.
pub fn localization_diagnostics(loc: &Localization) -> DiagnosticArray {
    let t_ = &loc.timings;
    let mut values = vec![
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
    if loc.fast_path_on_track {
        values.push(("fast_path_on_track", "true".to_string()));
    }
    if loc.last_resort {
        values.push(("last_resort", "true".to_string()));
    }
    if loc.confirm_search {
        values.push(("confirm_search", "true".to_string()));
    }
    if let Some(nfa) = loc.log10_nfa {
        values.push(("log10_nfa", format!("{nfa:.2}")));
    }
    if let Some(track) = loc.track {
        values.push(("track", track.name().to_string()));
    }
    if let Some(source) = loc.prediction {
        values.push(("prediction", source.name().to_string()));
    }
    let failure = loc.failure.as_ref().map(|f| f.to_string());
    diagnostics_msg(loc.stamp, loc.method.name(), &values, failure.as_deref())
}

/// Writes one frame's diagnostics; a negative stamp (a skipped frame) is logged at time 0, its
/// header keeping the stamp.
fn write_diagnostics(
    w: &mut BagWriter,
    stamp: Stamp,
    method: &str,
    values: &[(&str, String)],
    failure: Option<&str>,
) -> Result<()> {
    w.write(DIAGNOSTICS_TOPIC, stamp.max(0), &diagnostics_msg(stamp, method, values, failure))?;
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
    /// The covariance published with it (`pose_with_covariance`).
    covariance: Option<nalgebra::Matrix6<f64>>,
    kept: Vec<Correspondence>,
    ms: Option<f64>,
    /// The diagnostics' reason when the frame has no pose.
    failure: Option<String>,
}

/// An evaluated output bag.
pub struct Evaluation {
    pub method: String,
    pub summary: Summary,
    pub frames: Vec<FrameMetrics>,
    /// Frames without a pose, by reason: `skipped: …` (dropped for bad input), `failed: …`
    /// (the method found none), `missing from the output`.
    pub no_pose: BTreeMap<String, usize>,
    /// After the jumps of the ground truth (kidnaps), if any.
    pub recovery: Recovery,
}

/// Scores of one `eval` run: the matcher's raw inlier ratio and one evaluation per output bag.
pub struct EvalRun {
    pub raw: Summary,
    pub evaluations: Vec<Evaluation>,
    /// Frames of the input that lack ground truth (pose or depth) and so are not scored.
    pub without_ground_truth: usize,
}

/// The estimates of an output bag, by stamp, and the method it names.
struct Estimates {
    method: String,
    by_stamp: HashMap<Stamp, Estimate>,
}

fn read_estimates(est: &Path, topics: &TopicMap, max_record_bytes: u64) -> Result<Estimates> {
    let mut by_stamp: HashMap<Stamp, Estimate> = HashMap::new();
    let mut method = None;
    for m in BagMessages::open(est, ReadOptions { max_record_bytes, ..ReadOptions::default() })? {
        let m = m?;
        let topic = m.topic();
        let decode_err = || format!("{}: {topic} at log time {}", est.display(), m.log_time);
        if topic == topics.pose {
            let msg: msgs::PoseStamped = from_cdr(&m.data).with_context(decode_err)?;
            let pose = convert::isometry_from_pose(&msg.pose).with_context(decode_err)?;
            by_stamp.entry(convert::stamp(&msg.header)).or_default().pose = Some(pose);
        } else if topic == topics.pose_with_covariance {
            let msg: msgs::PoseWithCovarianceStamped = from_cdr(&m.data).with_context(decode_err)?;
            let covariance = convert::covariance_matrix(&msg.pose);
            by_stamp.entry(convert::stamp(&msg.header)).or_default().covariance = Some(covariance);
        } else if topic == topics.output_correspondences {
            let msg: msgs::Correspondences = from_cdr(&m.data).with_context(decode_err)?;
            let kept = convert::correspondences_from_msg(&msg).with_context(decode_err)?;
            by_stamp.entry(convert::stamp(&msg.header)).or_default().kept = kept;
        } else if topic == DIAGNOSTICS_TOPIC {
            let msg: DiagnosticArray = from_cdr(&m.data).with_context(decode_err)?;
            for status in msg.status.iter().filter(|s| s.name == STATUS_NAME) {
                let value = |key: &str| status.values.iter().find(|kv| kv.key == key).map(|kv| kv.value.clone());
                method = method.or_else(|| value("method"));
                let e = by_stamp.entry(convert::stamp(&msg.header)).or_default();
                if let Some(ms) = value("total_ms").and_then(|v| v.parse().ok()) {
                    e.ms = Some(ms);
                }
                if status.level != DiagnosticStatus::OK {
                    e.failure = Some(status.message.clone());
                }
            }
        }
    }
    Ok(Estimates { method: method.unwrap_or_else(|| est.display().to_string()), by_stamp })
}

/// The reason class of a failure message: its text up to the first ':' (numbers follow).
fn reason_class(message: &str) -> String {
    let head = message.split(':').next().unwrap_or(message).trim();
    head.chars().take(60).collect()
}

/// Scores every output bag in `ests` against the ground truth of the input bag, streaming the
/// input once. Every frame of the input (every stamp with a correspondences message) counts:
/// one dropped for bad input, one the method failed on and one missing from the output are
/// all not registered in RR, and `no_pose` says how many of each.
pub fn evaluate_bags(input: &Path, ests: &[std::path::PathBuf], params: &AppParams) -> Result<EvalRun> {
    let topics = &params.topics;
    let mut estimates = Vec::with_capacity(ests.len());
    for e in ests {
        estimates.push(
            read_estimates(e, topics, params.limits.max_record_bytes)
                .with_context(|| format!("evaluating {}", e.display()))?,
        );
    }
    let mut rows: Vec<Vec<FrameMetrics>> = vec![Vec::new(); ests.len()];
    let mut no_pose: Vec<BTreeMap<String, usize>> = vec![BTreeMap::new(); ests.len()];
    let (mut raw_rows, mut without_ground_truth) = (Vec::new(), 0usize);
    let mut track = Vec::new();
    let mut stream = FrameStream::open(input, topics, &params.limits)?.with_pixel_space(params.camera.pixels);
    while let Some(item) = stream.next_frame()? {
        let frame = match item {
            Assembled::Complete(f) | Assembled::Partial(f, _) => f,
            Assembled::Dropped(r) if r.has_correspondences && !r.repeat => {
                let first = r.errors.first().cloned().unwrap_or_else(|| format!("missing {}", r.missing.join(", ")));
                let reason = format!("skipped: {}", reason_class(&first));
                for (k, _) in ests.iter().enumerate() {
                    rows[k].push(FrameMetrics { stamp: r.stamp, inlier_ratio: 0.0, errors: None, ms: None });
                    *no_pose[k].entry(reason.clone()).or_default() += 1;
                }
                continue;
            }
            Assembled::Dropped(_) => continue,
        };
        let Some((gt_pose, gt_depth)) =
            frame.ground_truth.as_ref().and_then(|g| Some((g.pose.as_ref()?, g.depth.as_ref()?)))
        else {
            without_ground_truth += 1;
            continue;
        };
        track.push((frame.stamp, *gt_pose));
        let mask = inlier_mask(&frame.correspondences, &frame.intrinsics, gt_pose, gt_depth);
        raw_rows.push(FrameMetrics { stamp: frame.stamp, inlier_ratio: inlier_ratio(&mask), errors: None, ms: None });
        for (k, est) in estimates.iter_mut().enumerate() {
            let e = est.by_stamp.remove(&frame.stamp);
            let (kept, pose, ms) = e.as_ref().map_or((&[][..], None, None), |e| (&e.kept[..], e.pose, e.ms));
            let covariance = e.as_ref().and_then(|e| e.covariance);
            let mask = inlier_mask(kept, &frame.intrinsics, gt_pose, gt_depth);
            let errors = pose.map(|p| PoseErrors {
                nees: covariance.and_then(|c| nees(&p, gt_pose, &c)),
                ..pose_errors(&p, gt_pose, &frame.intrinsics, gt_depth)
            });
            if errors.is_none() {
                let reason = match e.as_ref().and_then(|e| e.failure.as_deref()) {
                    Some(f) => format!("failed: {}", reason_class(f)),
                    None if e.is_some() => "failed".to_string(),
                    None => "missing from the output".to_string(),
                };
                *no_pose[k].entry(reason).or_default() += 1;
            }
            rows[k].push(FrameMetrics { stamp: frame.stamp, inlier_ratio: inlier_ratio(&mask), errors, ms });
        }
    }
    anyhow::ensure!(
        !raw_rows.is_empty() || rows.iter().any(|r| !r.is_empty()),
        "{}: no frame with ground-truth pose and depth to score against",
        input.display()
    );
    let jumps = jumps(&track);
    let evaluations = estimates
        .into_iter()
        .zip(rows)
        .zip(no_pose)
        .map(|((est, frames), no_pose)| Evaluation {
            method: est.method,
            summary: summarize(&frames),
            recovery: recovery(&frames, &jumps),
            frames,
            no_pose,
        })
        .collect();
    Ok(EvalRun { raw: summarize(&raw_rows), evaluations, without_ground_truth })
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
/// (N×6: u, v, x, y, z, score). Beside them `model_constants.json`: the `network.*` values the
/// inputs were built with, which a model trained on them carries in its metadata
/// ([`crate::reject::model_constants`]; `training/train.py` stamps it).
pub fn export_samples(input: &Path, out: &Path, params: &AppParams) -> Result<ExportReport> {
    use crate::npy;
    use crate::reject::inputs::{build_inputs, IndexedMap, TensorValues};
    use crate::reject::model_constants::{write_export_file, EXPORT_FILE};
    use crate::reject::{FrameGeometry, SpectralRejector};

    let mut stream = FrameStream::open(input, &params.topics, &params.limits)?.with_pixel_space(params.camera.pixels);
    let map = stream.map.take().map(|m| IndexedMap::new(m.points));
    let core = &params.localizer;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    write_export_file(out, &core.network).with_context(|| format!("writing {}/{EXPORT_FILE}", out.display()))?;
    let mut spectral = SpectralRejector::new(core.network.keypoint_spectral(core.spectral.clone()));
    let mut report = ExportReport { samples: 0, skipped: Vec::new() };
    while let Some(item) = stream.next_frame()? {
        let frame = match item {
            Assembled::Complete(f) | Assembled::Partial(f, _) => f,
            Assembled::Dropped(r) => {
                report.skipped.push(describe(&r));
                continue;
            }
        };
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
        let geometry = FrameGeometry::build(&frame, core.depth_kind, core.network.alignment(&core.align));
        let inputs = build_inputs(&geometry, map.as_ref(), &mut spectral, &core.network);
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
        let n = geometry.len();
        let corr: Vec<f32> = frame
            .correspondences
            .iter()
            .flat_map(|c| {
                [c.pixel.x as f32, c.pixel.y as f32, c.point.x as f32, c.point.y as f32, c.point.z as f32, c.score]
            })
            .collect();
        let write =
            |name: &str, r: std::io::Result<()>| r.with_context(|| format!("writing {}/{name}.npy", dir.display()));
        // The network's inputs, as the ONNX run gets them (`matcher_score` is also column 6 of
        // `correspondences`).
        for t in inputs.tensors() {
            let path = dir.join(format!("{}.npy", t.name));
            let written = match &t.values {
                TensorValues::F32(v) => npy::write(&path, v, &t.shape),
                TensorValues::I64(v) => npy::write(&path, v, &t.shape),
            };
            write(t.name, written)?;
        }
        write("spectral", npy::write(&dir.join("spectral.npy"), &inputs.spectral_scores, &[n]))?;
        write("labels", npy::write(&dir.join("labels.npy"), &labels, &[n]))?;
        write("correspondences", npy::write(&dir.join("correspondences.npy"), &corr, &[n, 6]))?;
        report.samples += 1;
    }
    Ok(report)
}

/// `synth --out DIR` may replace DIR only when it does not exist, is empty, or `force` is set.
pub fn check_synth_out(out: &Path, force: bool) -> Result<()> {
    let Ok(meta) = std::fs::symlink_metadata(out) else { return Ok(()) };
    anyhow::ensure!(meta.is_dir(), "{} exists and is not a directory; refusing to replace it", out.display());
    let entries = std::fs::read_dir(out).with_context(|| format!("reading {}", out.display()))?.count();
    anyhow::ensure!(
        entries == 0 || force,
        "{} is not empty ({entries} entries); pass --force to delete it and write the bag there",
        out.display()
    );
    Ok(())
}

/// Lines saying, per evaluated bag, how many frames had no pose and why (empty when all had one).
pub fn format_no_pose(evaluations: &[Evaluation], without_ground_truth: usize) -> String {
    let mut out = String::new();
    for ev in evaluations.iter().filter(|ev| !ev.no_pose.is_empty()) {
        let total: usize = ev.no_pose.values().sum();
        let why: Vec<String> = ev.no_pose.iter().map(|(reason, n)| format!("{n} {reason}")).collect();
        out += &format!(
            "{}: {total} of {} frames without a pose (not registered): {}\n",
            ev.method,
            ev.summary.frames,
            why.join("; ")
        );
    }
    for ev in evaluations.iter().filter(|ev| ev.recovery.jumps > 0) {
        let r = &ev.recovery;
        out += &format!(
            "{}: {} jump(s) of the camera: a correct pose again within {} frame(s), {} never recovered, {} wrong \
             pose(s) published meanwhile\n",
            ev.method,
            r.jumps,
            r.frames_to_recover_max.map_or_else(|| "-".to_string(), |n| n.to_string()),
            r.unrecovered,
            r.wrong_while_recovering
        );
    }
    if without_ground_truth > 0 {
        out += &format!("{without_ground_truth} input frames lack ground-truth pose or depth and are not scored\n");
    }
    out
}
