//! `angle-i2p`: replay bags through the localizer, score output bags, make synthetic bags.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};

use angle_i2p::app::{self, describe, BagEdge};
use angle_i2p::eval::{format_table, median, Summary};
use angle_i2p::params::{resolve_cli, resolve_command, AppParams, TopicMap};
use angle_i2p::pipeline::{Localization, Localizer, Method};
use angle_i2p::synth::{SynthConfig, PRESETS};

#[derive(Parser)]
#[command(
    name = "angle-i2p",
    version,
    about = "Camera localization against a point map with Angle-I2P outlier rejection"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// A bag command's topic remaps, as the node's `--ros-args -r`.
#[derive(clap::Args)]
struct Remaps {
    /// Topic remap `FROM:=TO` (e.g. `/matcher/correspondences:=/my/matches`): read and write
    /// TO where angle-i2p's default is FROM; repeatable.
    #[arg(short = 'r', long = "remap", value_name = "FROM:=TO")]
    rules: Vec<String>,
}

#[derive(Subcommand)]
enum Command {
    /// Localize every frame of a rosbag2 bag and write the results to a new bag.
    Replay {
        /// Input bag: a rosbag2 directory or a bare .mcap file.
        bag: PathBuf,
        /// Output bag directory (must not exist yet).
        #[arg(long)]
        out: PathBuf,
        /// Outlier rejection before PnP (overrides the params file).
        #[arg(long, value_enum)]
        method: Option<Method>,
        /// ROS 2 params file (default: none, built-in defaults = params/angle_i2p.yaml).
        #[arg(long)]
        params_file: Option<PathBuf>,
        /// Parameter override `NAME:=VALUE` (dotted names, e.g. `network.tau:=0.4`); repeatable,
        /// applied after the params file.
        #[arg(short = 'p', long = "param", value_name = "NAME:=VALUE")]
        param: Vec<String>,
        #[command(flatten)]
        remap: Remaps,
        /// Print one line per frame.
        #[arg(long)]
        verbose: bool,
    },
    /// Score output bags against the ground truth of the input bag: IR, RR, MRE, MTE, ms/frame.
    Eval {
        /// Input bag with /ground_truth/pose and /ground_truth/depth.
        bag: PathBuf,
        /// Output bag(s) of `replay`; one table row each.
        #[arg(long = "est", required = true)]
        est: Vec<PathBuf>,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
        #[arg(long)]
        params_file: Option<PathBuf>,
        /// Also write plots and an `index.html` with the table into this directory.
        #[arg(long)]
        report: Option<PathBuf>,
        #[command(flatten)]
        remap: Remaps,
    },
    /// Write training samples for the learned rejector (features, graphs, θ, labels) from a bag
    /// with ground truth: one folder of `.npy` arrays per frame.
    Export {
        bag: PathBuf,
        #[arg(long)]
        out: PathBuf,
        #[arg(long)]
        params_file: Option<PathBuf>,
        /// Parameter override `NAME:=VALUE` (dotted names, e.g. `network.tau:=0.4`); repeatable,
        /// applied after the params file.
        #[arg(short = 'p', long = "param", value_name = "NAME:=VALUE")]
        param: Vec<String>,
        #[command(flatten)]
        remap: Remaps,
    },
    /// Print the last `/diagnostics` status of each name recorded in a bag (e.g. `node --record`).
    Diagnostics { bag: PathBuf },
    /// Print the effective parameters as a ROS 2 params file.
    Params {
        #[arg(long)]
        params_file: Option<PathBuf>,
        /// Parameter override `NAME:=VALUE` (dotted names, e.g. `network.tau:=0.4`); repeatable,
        /// applied after the params file.
        #[arg(short = 'p', long = "param", value_name = "NAME:=VALUE")]
        param: Vec<String>,
    },
    /// Run the live ROS 2 node over DDS (ros2-client/RustDDS) until SIGINT/SIGTERM.
    ///
    /// Respects ROS_DOMAIN_ID. ROS arguments go last: `--ros-args -r from:=to -p name:=value
    /// --params-file F -r __ns:=/ns -r __node:=name`.
    Node {
        /// ROS 2 params file (applied before the `--ros-args` ones).
        #[arg(long)]
        params_file: Option<PathBuf>,
        /// Also write everything the node publishes to this new bag directory.
        #[arg(long)]
        record: Option<PathBuf>,
        /// `--ros-args` and everything after it.
        #[arg(long = "ros-args", num_args = 0.., allow_hyphen_values = true, value_name = "ARGS")]
        ros_args: Option<Vec<String>>,
    },
    /// Publish a bag's messages over DDS with their recorded timing (like `ros2 bag play`).
    Play(angle_i2p::play::PlayArgs),
    /// Write a synthetic bag (room of planes and boxes, camera path, ground truth).
    Synth {
        /// Output bag directory (must not exist or be empty, unless --force).
        #[arg(long)]
        out: PathBuf,
        /// Replace a non-empty --out directory (everything in it is deleted).
        #[arg(long)]
        force: bool,
        /// Tier: sift, hard, extreme, easy or building (hard in a building), with +MODIFIERs.
        #[arg(long, default_value = "hard")]
        preset: String,
        /// JSON/YAML file with SynthConfig fields overriding the preset.
        #[arg(long)]
        config: Option<PathBuf>,
        #[arg(long)]
        seed: Option<u64>,
        #[arg(long)]
        frames: Option<usize>,
        #[arg(long)]
        inlier_ratio: Option<f64>,
        #[arg(long)]
        correspondences: Option<usize>,
        /// About this many map points (the sampled map plus points on the same surfaces).
        #[arg(long)]
        map_points: Option<usize>,
    },
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Replay { bag, out, method, params_file, param, remap, verbose } => {
            let mut params = resolve_command(params_file.as_deref(), &param, &remap.rules)?;
            if let Some(m) = method {
                params.localizer.method = m;
            }
            app::work_on_this_thread();
            replay(&bag, &out, &params, verbose)
        }
        Command::Node { params_file, record, ros_args } => {
            let ros_args = match ros_args {
                Some(rest) => std::iter::once("--ros-args".to_string()).chain(rest).collect(),
                None => Vec::new(),
            };
            angle_i2p::node::run(angle_i2p::node::NodeConfig { params_file, ros_args, record })
        }
        Command::Play(args) => {
            let report = angle_i2p::play::play(&args)?;
            println!("{report}");
            Ok(())
        }
        Command::Export { bag, out, params_file, param, remap } => {
            let params = resolve_command(params_file.as_deref(), &param, &remap.rules)?;
            let report = app::export_samples(&bag, &out, &params)?;
            for s in &report.skipped {
                eprintln!("warning: {s}");
            }
            println!("{} samples → {}", report.samples, out.display());
            Ok(())
        }
        Command::Diagnostics { bag } => print_diagnostics(&bag),
        Command::Params { params_file, param } => {
            let params = resolve_cli(params_file.as_deref(), &param)?;
            print_params_file(&params)
        }
        Command::Eval { bag, est, json, params_file, report, remap } => {
            let params = resolve_command(params_file.as_deref(), &[] as &[&str], &remap.rules)?;
            evaluate(&bag, &est, json, &params, report.as_deref())
        }
        Command::Synth { out, preset, config, seed, frames, inlier_ratio, correspondences, map_points, force } => {
            app::check_synth_out(&out, force)?;
            let mut cfg = synth_config(&preset, config.as_deref())?;
            cfg.seed = seed.unwrap_or(cfg.seed);
            cfg.frames = frames.unwrap_or(cfg.frames);
            cfg.inlier_ratio = inlier_ratio.unwrap_or(cfg.inlier_ratio);
            cfg.correspondences = correspondences.unwrap_or(cfg.correspondences);
            if let Some(n) = map_points {
                cfg.map_points = n;
            }
            synth(&preset, &cfg, &out)
        }
    }
}

/// `replay`: every frame of `bag` through the localizer into the new bag `out`, with a progress bar.
fn replay(bag: &Path, out: &Path, params: &AppParams, verbose: bool) -> Result<()> {
    let method = params.localizer.method;
    let mut localizer =
        Localizer::new(params.localizer.clone()).map_err(|e| anyhow::anyhow!("method {}: {e}", method.name()))?;
    let bar = ProgressBar::new(0).with_style(
        ProgressStyle::with_template("{prefix} [{bar:30}] {pos}/{len} frames, {per_sec} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_prefix(format!("replay {}", localizer.params().method.name()));
    let (mut scored, mut registered) = (0usize, 0usize);
    let report = app::replay(bag, out, &mut localizer, BagEdge::of(params), |progress| {
        let loc = progress.localization;
        bar.set_length(progress.expected as u64);
        bar.set_position(progress.index as u64 + 1);
        if let Some(r) = progress.registered {
            scored += 1;
            registered += r as usize;
        }
        let rr = (scored > 0)
            .then(|| format!(", RR {:.1} % ({registered}/{scored})", 100.0 * registered as f64 / scored as f64))
            .unwrap_or_default();
        bar.set_message(format!("{:.2} ms{rr}", loc.timings.total_ms));
        if verbose {
            let line = frame_line(loc);
            if bar.is_hidden() {
                eprintln!("{line}")
            } else {
                bar.println(line)
            }
        }
    })?;
    bar.finish_and_clear();
    print_replay_summary(&localizer, &report, out);
    Ok(())
}

/// `replay --verbose`: one line per frame.
fn frame_line(loc: &Localization) -> String {
    let fast_path = match (loc.fast_path, &loc.fast_path_check) {
        (true, _) if loc.fast_path_on_track => ", settled by the fast path on the track".to_string(),
        (true, _) => ", settled by the fast path".to_string(),
        (false, _) if loc.last_resort => ", pose from the last resort (plain LO-RANSAC)".to_string(),
        (false, Some(c)) => {
            format!(
                ", fast path unsettled (inliers {:.2}, cells {:.2}, log10 NFA {:.1})",
                c.inlier_ratio, c.cell_share, c.log10_nfa
            )
        }
        _ => String::new(),
    };
    format!(
        "frame {}: {} kept, {} inliers, {} hypotheses in {} robust passes, {:.2} ms (fast path {:.2}, geometry {:.2}, \
         reject {:.2}, pnp {:.2}){}{}{}{}{}{}{}",
        loc.stamp,
        loc.kept.len(),
        loc.num_inliers,
        loc.pnp_iterations,
        loc.robust_passes,
        loc.timings.total_ms,
        loc.timings.fast_path_ms,
        loc.timings.geometry_ms,
        loc.timings.reject_ms,
        loc.timings.pnp_ms,
        fast_path,
        loc.prior_quality.map(|q| format!(", prior quality {q:.2}")).unwrap_or_default(),
        loc.log10_nfa.map(|n| format!(", log10 NFA {n:.1}")).unwrap_or_default(),
        if loc.confirm_search { ", checked by the plain search going on over every match" } else { "" },
        loc.track.map(|t| format!(", {}", t.name())).unwrap_or_default(),
        loc.prediction.map(|p| format!(" (predicted by {})", p.name())).unwrap_or_default(),
        loc.failure.as_ref().map(|f| format!(" — no pose: {f}")).unwrap_or_default()
    )
}

/// The warnings of a replay, its one-line summary and the frames without a pose.
fn print_replay_summary(localizer: &Localizer, report: &app::ReplayReport, out: &Path) {
    for f in &report.incomplete {
        eprintln!("warning: {}", describe(f));
    }
    for issue in &report.issues {
        eprintln!("warning: {issue}");
    }
    let ms: Vec<f64> = report.localizations.iter().map(|l| l.timings.total_ms).collect();
    let posed = report.localizations.iter().filter(|l| l.pose.is_some()).count();
    println!(
        "{}: {} frames, {} with a pose, {} skipped; ms/frame median {:.2}, mean {:.2}, max {:.2} → {}",
        localizer.params().method.name(),
        report.localizations.len(),
        posed,
        report.incomplete.iter().filter(|f| f.dropped).count(),
        median(&ms).unwrap_or(0.0),
        angle_i2p::eval::mean(&ms).unwrap_or(0.0),
        ms.iter().copied().fold(0.0, f64::max),
        out.display()
    );
    for l in report.localizations.iter().filter(|l| l.failure.is_some()) {
        if let Some(f) = &l.failure {
            eprintln!("frame {}: no pose: {f}", l.stamp);
        }
    }
}

/// `diagnostics`: the last `/diagnostics` status of each name in a bag.
fn print_diagnostics(bag: &Path) -> Result<()> {
    let reader = angle_i2p::bag::BagReader::open(bag)?;
    let mut last = std::collections::BTreeMap::new();
    for m in reader.messages().iter().filter(|m| m.topic() == app::DIAGNOSTICS_TOPIC) {
        let msg: angle_i2p::msgs::DiagnosticArray = angle_i2p::msgs::from_cdr(&m.data)
            .with_context(|| format!("{}: /diagnostics at {}", bag.display(), m.log_time))?;
        for status in msg.status {
            last.insert(status.name.clone(), status);
        }
    }
    anyhow::ensure!(!last.is_empty(), "{}: no {} messages", bag.display(), app::DIAGNOSTICS_TOPIC);
    for (name, status) in last {
        println!("{name}: {}", status.message);
        for kv in status.values {
            println!("  {} = {}", kv.key, kv.value);
        }
    }
    Ok(())
}

/// `params`: the effective parameters as a ROS 2 params file.
fn print_params_file(params: &AppParams) -> Result<()> {
    let mut node = serde_yaml::Mapping::new();
    node.insert("ros__parameters".into(), serde_yaml::to_value(params)?);
    let mut doc = serde_yaml::Mapping::new();
    doc.insert("angle_i2p".into(), serde_yaml::Value::Mapping(node));
    print!("{}", serde_yaml::to_string(&doc)?);
    Ok(())
}

/// `eval`: the table (or JSON) of every output bag against the input's ground truth, and the
/// report when asked for.
fn evaluate(bag: &Path, est: &[PathBuf], json: bool, params: &AppParams, report: Option<&Path>) -> Result<()> {
    let run = app::evaluate_bags(bag, est, params)?;
    let mut rows = vec![("raw matches (IR only)".to_string(), run.raw.clone())];
    let mut evaluations = run.evaluations;
    // Rows of one method (variants of it) are told apart by their output directory.
    let methods: Vec<String> = evaluations.iter().map(|ev| ev.method.clone()).collect();
    for (ev, e) in evaluations.iter_mut().zip(est) {
        if methods.iter().filter(|m| **m == ev.method).count() > 1 {
            let dir = e.file_name().map_or_else(|| e.display().to_string(), |n| n.to_string_lossy().into_owned());
            ev.method = format!("{} ({dir})", ev.method);
        }
        rows.push((ev.method.clone(), ev.summary.clone()));
    }
    if json {
        println!("{}", evaluations_json(&evaluations)?);
    } else {
        println!("{}", bag.display());
        print!("{}", format_table(&rows));
        print!("{}", app::format_no_pose(&evaluations, run.without_ground_truth));
    }
    if let Some(dir) = report {
        // The pictures need every frame at once (ground truth, images): read apart from
        // the streaming evaluation, only when asked for.
        let input = angle_i2p::bag::read_frames_limited(bag, &params.topics, &params.limits)?;
        write_report(bag, &input, &params.topics, &rows[0].1, &evaluations, est, dir)?;
    }
    Ok(())
}

/// `eval --json`: one object per output bag, its summary and why frames have no pose.
fn evaluations_json(evaluations: &[app::Evaluation]) -> Result<String> {
    let obj: serde_json::Map<String, serde_json::Value> = evaluations
        .iter()
        .map(|ev| {
            let mut row = serde_json::to_value(&ev.summary)?;
            if let Some(o) = row.as_object_mut() {
                o.insert("no_pose".into(), serde_json::to_value(&ev.no_pose)?);
                o.insert("recovery".into(), serde_json::to_value(&ev.recovery)?);
            }
            Ok((ev.method.clone(), row))
        })
        .collect::<Result<_>>()?;
    Ok(serde_json::to_string_pretty(&obj)?)
}

/// `eval --report DIR`: the evaluations' plots and page (see `angle_i2p::report`).
fn write_report(
    bag: &Path,
    input: &angle_i2p::bag::BagFrames,
    topics: &TopicMap,
    raw: &Summary,
    evaluations: &[app::Evaluation],
    est: &[PathBuf],
    dir: &Path,
) -> Result<()> {
    use angle_i2p::report::{MethodRun, ReportInput};
    let runs = evaluations
        .iter()
        .zip(est)
        .map(|(ev, e)| MethodRun { label: ev.method.clone(), est: e.clone(), evaluation: ev })
        .collect();
    let report_input = ReportInput { bag_path: bag, bag: input, topics, raw, runs };
    let files = angle_i2p::report::write_report(&report_input, dir)
        .with_context(|| format!("writing the report into {}", dir.display()))?;
    eprintln!("report: {} files → {}", files.files.len(), dir.join("index.html").display());
    Ok(())
}

/// The preset `preset`, with the fields of the `--config` file over it.
fn synth_config(preset: &str, config: Option<&Path>) -> Result<SynthConfig> {
    let Some(cfg) = SynthConfig::preset(preset) else {
        bail!("unknown preset {preset:?}: one of {}, building", PRESETS.join(", "));
    };
    let Some(path) = config else { return Ok(cfg) };
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    // Fields of the file override the preset's.
    let mut base = serde_yaml::to_value(&cfg)?;
    let over: serde_yaml::Value = serde_yaml::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
    if let (Some(b), Some(o)) = (base.as_mapping_mut(), over.as_mapping()) {
        for (k, v) in o {
            b.insert(k.clone(), v.clone());
        }
    }
    serde_yaml::from_value(base).with_context(|| format!("{}", path.display()))
}

/// `synth`: the scene of `cfg` written as an input bag at `out` (replaced if there).
fn synth(preset: &str, cfg: &SynthConfig, out: &Path) -> Result<()> {
    if out.exists() {
        std::fs::remove_dir_all(out).with_context(|| format!("replacing {}", out.display()))?;
    }
    // Frames are made and written batch by batch: memory does not grow with --frames.
    let written = angle_i2p::synth::write_bag(out, &TopicMap::default(), cfg)?;
    println!(
        "synth {preset} (seed {}): {} frames, {} map points, mean inlier ratio {:.3} → {}",
        cfg.seed,
        written.frames,
        written.map_points,
        written.mean_inlier_ratio,
        out.display()
    );
    Ok(())
}
