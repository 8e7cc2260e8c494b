#!/usr/bin/env python3
"""Side-by-side benchmark: angle-i2p's methods against PoseLib's LO-RANSAC, bag by bag, in one run.

    side_by_side.py [BAG ...] [--synth PRESET ...] --out DIR [--methods default,alone,ransac]
                    [--method consistency] [--params-file F] [-p NAME:=VALUE ...]
                    [--bag-param GLOB:NAME:=VALUE ...] [--rounds N] [--binary PATH] [--strict]

For each bag: `angle-i2p replay` once per method (the default method, tracking; the same with
frames alone; then `ransac`, plus any `--method`), `angle-i2p eval --json` on each output, and PoseLib 2.0.5's LO-RANSAC (P3P, <= 10k
iterations, >= 100, 8 px, success probability 0.9999) on the bag's raw correspondences, timed
per frame around the estimate call alone. Prints one markdown table per bag (RR, MRE, MTE,
median ms per frame, time relative to PoseLib, and the verdict against the acceptance criteria
of the bag's tier) and writes DIR/side_by_side.json (every summary and every frame, with the
failure reasons replay wrote to /diagnostics) and DIR/side_by_side.md (the tables).

`--synth PRESET` adds a bag that `angle-i2p synth` makes (seed --synth-seed, --synth-frames
frames) in DIR/bags/synth-PRESET. Per-bag parameters: `--bag-param 'GLOB:NAME:=VALUE'` (GLOB
matched against the bag's name or path) or a file `side_by_side.yaml` inside the bag directory
holding `params: {NAME: VALUE}`; both become `-p NAME:=VALUE` of that bag's replays, after the
global `-p`s.
"""
from __future__ import annotations

import argparse
import dataclasses
import fnmatch
import json
import os
import pathlib
import shutil
import subprocess
import sys
import time

import numpy as np
from rosbags.highlevel import AnyReaderError

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import bag_scoring  # noqa: E402
import side_by_side_report as report  # noqa: E402

POSELIB_LABEL = "PoseLib LO-RANSAC (10k it, 8 px)"
POSELIB_RANSAC = {"max_reproj_error": 8.0, "max_iterations": 10000, "min_iterations": 100, "success_prob": 0.9999}
MIN_CORRESPONDENCES = 6
BAG_PARAMS_FILE = "side_by_side.yaml"


class BenchError(Exception):
    """A step of the benchmark that failed; the message says which command or file."""


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("bags", nargs="*", type=pathlib.Path, help="rosbag2 directories (or bare .mcap files)")
    ap.add_argument("--out", type=pathlib.Path, required=True, help="directory for output bags and the JSON")
    ap.add_argument("--methods", default="default,alone,ransac",
                    help="comma-separated replay methods; 'default' runs replay without --method, 'alone' the "
                         "default method with frames alone (tracking off) (default: %(default)s)")
    ap.add_argument("--method", action="append", default=[], help="one more replay method (repeatable)")
    ap.add_argument("--params-file", type=pathlib.Path, help="ROS 2 params file for every replay and eval")
    ap.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                    help="parameter override for every replay (repeatable)")
    ap.add_argument("-r", "--remap", action="append", default=[], metavar="FROM:=TO",
                    help="topic remap for every replay and eval, as `angle-i2p replay -r` (repeatable)")
    ap.add_argument("--bag-param", action="append", default=[], metavar="GLOB:NAME:=VALUE",
                    help="parameter override for the bags whose name or path matches GLOB (repeatable)")
    ap.add_argument("--binary", type=pathlib.Path, help="the angle-i2p binary (default: $ANGLE_I2P_BIN, "
                    "$CARGO_TARGET_DIR/release/angle-i2p, target/release/angle-i2p, then PATH)")
    ap.add_argument("--rounds", type=int, default=1,
                    help="timing rounds: every replay and PoseLib run this often, interleaved; a frame's time is "
                    "its median over the rounds, the metrics are the first round's (default: %(default)s)")
    ap.add_argument("--synth", action="append", default=[], metavar="PRESET",
                    help="also a bag made by `angle-i2p synth --preset PRESET` into DIR/bags/synth-PRESET (repeatable)")
    ap.add_argument("--synth-seed", type=int, default=1, help="seed of the --synth bags (default: %(default)s)")
    ap.add_argument("--synth-frames", type=int, default=20, help="frames of the --synth bags (default: %(default)s)")
    ap.add_argument("--strict", action="store_true", help="exit with status 1 when a verdict is FAIL")
    return ap.parse_args(argv)


def find_binary(given: pathlib.Path | None) -> pathlib.Path:
    repo = pathlib.Path(__file__).resolve().parent.parent
    candidates = [given] if given else [
        pathlib.Path(os.environ["ANGLE_I2P_BIN"]) if os.environ.get("ANGLE_I2P_BIN") else None,
        pathlib.Path(os.environ["CARGO_TARGET_DIR"]) / "release/angle-i2p" if os.environ.get("CARGO_TARGET_DIR") else None,
        repo / "target/release/angle-i2p",
        pathlib.Path(shutil.which("angle-i2p")) if shutil.which("angle-i2p") else None]
    for c in candidates:
        if c is not None and c.is_file() and os.access(c, os.X_OK):
            return c.resolve()
    raise BenchError(f"no angle-i2p binary (tried {', '.join(str(c) for c in candidates if c)}); "
                     "build it with `cargo build --release` or pass --binary")


def run(cmd: list) -> str:
    proc = subprocess.run([str(c) for c in cmd], capture_output=True, text=True)
    if proc.returncode != 0:
        raise BenchError(f"`{' '.join(str(c) for c in cmd)}` failed (status {proc.returncode}):\n{proc.stderr.strip()}")
    return proc.stdout


def bag_name(bag: pathlib.Path) -> str:
    """The bag's name as given (a symlink keeps its own name, which may carry the tier)."""
    bag = pathlib.Path(os.path.abspath(bag))
    return bag.stem if bag.suffix == ".mcap" else bag.name


def bag_params(bag: pathlib.Path, bag_param_flags: list[str]) -> list[str]:
    """The bag's own `NAME:=VALUE` overrides: from its side_by_side.yaml, then from matching --bag-param flags."""
    params = []
    file = bag / BAG_PARAMS_FILE
    if bag.is_dir() and file.is_file():
        from ruamel.yaml import YAML  # rosbags' YAML library, in the eval venv
        from ruamel.yaml import YAMLError
        try:
            doc = YAML(typ="safe").load(file.read_text()) or {}
        except YAMLError as e:
            raise BenchError(f"{file}: not YAML: {e}") from e
        mapping = doc.get("params", {}) if isinstance(doc, dict) else None
        if not isinstance(mapping, dict):
            raise BenchError(f"{file}: expected a mapping `params: {{NAME: VALUE}}`")
        params += [f"{k}:={str(v).lower() if isinstance(v, bool) else v}" for k, v in mapping.items()]
    for flag in bag_param_flags:
        glob, sep, assignment = flag.partition(":")
        if not sep or ":=" not in assignment:
            raise BenchError(f"--bag-param {flag!r}: expected GLOB:NAME:=VALUE")
        if fnmatch.fnmatch(bag_name(bag), glob) or fnmatch.fnmatch(str(bag), glob):
            params.append(assignment)
    return params


def params_args(args: argparse.Namespace, extra: list[str]) -> list[str]:
    out = ["--params-file", str(args.params_file)] if args.params_file else []
    for p in [*args.param, *extra]:
        out += ["-p", p]
    return out


# angle-i2p's topic names (src/params/topics.rs); renamed only by remap rules, as in ROS.
DEFAULT_TOPICS = {
    "map": "/map/points", "camera_info": "/camera/camera_info", "image": "/camera/image_raw/compressed",
    "depth_prior": "/depth_prior/image", "correspondences": "/matcher/correspondences",
    "ground_truth_pose": "/ground_truth/pose", "ground_truth_depth": "/ground_truth/depth",
    "pose": "/angle_i2p/pose", "pose_with_covariance": "/angle_i2p/pose_with_covariance",
    "output_correspondences": "/angle_i2p/correspondences",
}


def topics(remaps: list[str]) -> dict:
    """The topic names under `FROM:=TO` remap rules (names without `/` are taken from the root)."""
    absolute = lambda name: name if name.startswith("/") else "/" + name
    rules = []
    for rule in remaps:
        if ":=" not in rule:
            raise BenchError(f"remap rule {rule!r} is not FROM:=TO")
        src, dst = rule.split(":=", 1)
        rules.append((absolute(src), absolute(dst)))
    return {key: next((dst for src, dst in rules if src == name), name) for key, name in DEFAULT_TOPICS.items()}


@dataclasses.dataclass
class BagRuns:
    """What every run on one bag shares."""
    binary: pathlib.Path
    bag: pathlib.Path
    out_dir: pathlib.Path
    param_args: list  # --params-file, -p and -r arguments of every replay
    eval_args: list  # --params-file and -r of eval
    topics: dict
    frames: list  # bag_scoring.InputFrame, in stamp order

    def run_dir(self, method: str, round_index: int = 0) -> pathlib.Path:
        name = method.replace("/", "_")
        return self.out_dir / (name if round_index == 0 else f"{name}.round{round_index}")

    def replay(self, method: str, run_dir: pathlib.Path) -> list[str]:
        """`angle-i2p replay` into `run_dir` (replaced) with `method` ('default': no --method; 'alone':
        the default method with frames alone, tracking off); its arguments."""
        if run_dir.exists():
            shutil.rmtree(run_dir)
        run_dir.parent.mkdir(parents=True, exist_ok=True)
        method_args = {"default": [], "alone": ["-p", "tracking.enabled:=false"]}.get(method, ["--method", method])
        run([self.binary, "replay", self.bag, "--out", run_dir, *method_args, *self.param_args])
        return [*method_args, *self.param_args]


def replay_and_eval(ctx: BagRuns, method: str) -> dict:
    """One replay of the bag with `method`, its eval summary and its frames."""
    run_dir = ctx.run_dir(method)
    replay_args = ctx.replay(method, run_dir)
    evaluated = json.loads(run([ctx.binary, "eval", ctx.bag, "--est", run_dir, "--json", *ctx.eval_args]))
    if len(evaluated) != 1:
        raise BenchError(f"eval of {run_dir} printed {len(evaluated)} rows, expected 1")
    (name, summary), = evaluated.items()
    outputs = bag_scoring.read_output(run_dir, ctx.topics["pose"])
    rows = []
    for f in ctx.frames:
        o = outputs.get(f.stamp, bag_scoring.OutputFrame(failure="no output for this frame"))
        rows.append(bag_scoring.frame_row(f, o.pose, o.ms, o.failure, kept=o.kept, pnp_inliers=o.pnp_inliers))
    label = {"default": f"{name} (default)", "alone": f"{name} (frames alone)"}.get(method, name)
    return {"label": label, "method": name, "replay_args": replay_args, "output_bag": str(run_dir),
            "summary": summary, "eval_summary": summary, "rescored": bag_scoring.summarize(rows), "frames": rows}


def replay_times(ctx: BagRuns, method: str, round_index: int) -> list:
    """Per frame, the ms of one more replay (a timing round); its output bag is removed after."""
    run_dir = ctx.run_dir(method, round_index)
    ctx.replay(method, run_dir)
    outputs = bag_scoring.read_output(run_dir, ctx.topics["pose"])
    shutil.rmtree(run_dir)
    return [outputs[f.stamp].ms if f.stamp in outputs else None for f in ctx.frames]


def add_timing_round(run_result: dict, times: list) -> None:
    for row, ms in zip(run_result["frames"], times):
        row.setdefault("ms_rounds", [row["ms"]]).append(ms)


def settle_timing(run_result: dict, rounds: int) -> None:
    """With several rounds, a frame's ms is its median over the rounds, and the row's times follow."""
    if rounds < 2:
        return
    for row in run_result["frames"]:
        measured = [ms for ms in row["ms_rounds"] if ms is not None]
        row["ms"] = float(np.median(measured)) if measured else None
    rescored = bag_scoring.summarize(run_result["frames"])
    run_result["summary"] = {**run_result["summary"], "median_ms": rescored["median_ms"],
                             "ms_per_frame": rescored["ms_per_frame"], "timing_rounds": rounds}


def poselib_frame(frame: bag_scoring.InputFrame) -> dict:
    """PoseLib on one frame's raw correspondences, timed around the estimate call only."""
    import poselib
    corr = frame.correspondences
    if corr is None or len(corr) < MIN_CORRESPONDENCES:
        n = 0 if corr is None else len(corr)
        return bag_scoring.frame_row(frame, None, None, f"{n} correspondences (< {MIN_CORRESPONDENCES})")
    k, cam = frame.camera.k, frame.camera
    camera = {"model": "PINHOLE", "width": cam.width, "height": cam.height,
              "params": [k[0, 0], k[1, 1], k[0, 2], k[1, 2]]}
    pixels, points = np.ascontiguousarray(corr[:, :2]), np.ascontiguousarray(corr[:, 2:5])
    start = time.perf_counter()
    pose, info = poselib.estimate_absolute_pose(pixels, points, camera, POSELIB_RANSAC, {})
    ms = (time.perf_counter() - start) * 1e3
    inliers, iterations = int(info["num_inliers"]), int(info["iterations"])
    if inliers < MIN_CORRESPONDENCES:
        return bag_scoring.frame_row(frame, None, ms, f"PoseLib: {inliers} inliers (< {MIN_CORRESPONDENCES})",
                                     inliers=inliers, iterations=iterations)
    est = np.eye(4)
    est[:3, :3] = pose.R.T  # PoseLib's pose maps world to camera; ours is camera-to-map
    est[:3, 3] = -pose.R.T @ pose.t
    return bag_scoring.frame_row(frame, est, ms, None, inliers=inliers, iterations=iterations)


def poselib_run(frames: list) -> dict:
    rows = [poselib_frame(f) for f in frames]
    summary = bag_scoring.summarize(rows)
    return {"label": POSELIB_LABEL, "method": "poselib", "options": POSELIB_RANSAC, "summary": summary,
            "frames": rows}


def bench_bag(args, binary: pathlib.Path, bag: pathlib.Path, out_dir: pathlib.Path, methods: list[str]) -> dict:
    """Every method's replay and PoseLib on one bag, their timing rounds and verdicts."""
    extra = bag_params(bag, args.bag_param)
    remap_args = [a for rule in args.remap for a in ("-r", rule)]
    param_args = params_args(args, extra) + remap_args
    topic_map = topics(args.remap)
    inputs, issues = bag_scoring.read_input(bag, topic_map)
    frames = [f for _, f in sorted(inputs.items()) if f.scorable() and f.correspondences is not None]
    if not frames:
        raise BenchError(f"{bag}: no frame with camera info, correspondences, ground-truth pose and depth")
    eval_args = (["--params-file", str(args.params_file)] if args.params_file else []) + remap_args
    ctx = BagRuns(binary, bag, out_dir, param_args, eval_args, topic_map, frames)
    runs = [replay_and_eval(ctx, m) for m in methods]
    poselib = poselib_run(frames)
    for round_index in range(1, args.rounds):  # interleaved, so that the machine's load hits every row alike
        for r, m in zip(runs, methods):
            add_timing_round(r, replay_times(ctx, m, round_index))
        add_timing_round(poselib, [poselib_frame(f)["ms"] for f in frames])
    for r in [*runs, poselib]:
        settle_timing(r, args.rounds)
    tier = report.tier_of(bag_name(bag))
    oracle_rr = oracle_recall(bag)
    for r in runs:
        r["failed_criteria"] = report.criteria_failures(tier, r["summary"], poselib["summary"], oracle_rr)
    return {"bag": str(bag), "name": bag_name(bag), "tier": tier.__dict__ if tier else None, "bag_params": extra,
            "read_issues": issues, "runs": runs, "poselib": poselib, "oracle_RR": oracle_rr}


def oracle_recall(bag: pathlib.Path) -> float | None:
    """The single-frame oracle's RR (RANSAC on the true inliers alone) from the bag's
    baseline.json (the shared bags have one), or None."""
    path = (bag if bag.is_dir() else bag.parent) / "baseline.json"
    try:
        rows = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    oracle = [row["RR"] for name, row in rows.items() if name.startswith("oracle") and "RR" in row]
    return float(oracle[0]) if oracle else None


def synth_bags(args, binary: pathlib.Path) -> list[pathlib.Path]:
    """The --synth presets as bags in DIR/bags (made anew, deterministic for a seed)."""
    bags = []
    for preset in args.synth:
        bag = args.out / "bags" / f"synth-{preset}"
        run([binary, "synth", "--preset", preset, "--seed", args.synth_seed, "--frames", args.synth_frames,
             "--out", bag])
        bags.append(bag)
    return bags


def bench_all(args, binary: pathlib.Path, bags: list[pathlib.Path], methods: list[str]) -> list[dict]:
    """Every bag in turn; a bag that fails is reported (printed and in the JSON) and the others go on."""
    results, keys = [], set()
    for bag in bags:
        key = bag_name(bag)
        key = key if key not in keys else f"{key}-{len(keys)}"
        keys.add(key)
        try:
            if not bag.exists():
                raise BenchError(f"{bag}: no such bag")
            result = bench_bag(args, binary, bag, args.out / key, methods)
            result["table"] = report.markdown_table(result)
        except (BenchError, AnyReaderError, OSError) as e:
            message = str(e) if isinstance(e, BenchError) else f"{bag}: {e}"
            result = {"bag": str(bag), "name": key, "error": message, "table": f"### {key}\n\nerror: {message}\n"}
            print(f"error: {message}", file=sys.stderr)
        print(result["table"], flush=True)
        results.append(result)
    return results


def main(argv=None) -> int:
    args = parse_args(argv)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()] + args.method
    if not methods:
        print("error: no method to run (--methods is empty)", file=sys.stderr)
        return 2
    if args.rounds < 1:
        print(f"error: --rounds {args.rounds}: at least 1", file=sys.stderr)
        return 2
    if not args.bags and not args.synth:
        print("error: no bag to run (give BAGs or --synth PRESET)", file=sys.stderr)
        return 2
    try:
        binary = find_binary(args.binary)
        bags = [*args.bags, *synth_bags(args, binary)]
    except BenchError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    results = bench_all(args, binary, bags, methods)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "side_by_side.md").write_text("\n".join(r["table"] for r in results))
    document = {"binary": str(binary), "methods": methods, "timing_rounds": args.rounds,
                "poselib_options": POSELIB_RANSAC, "criteria": report.CRITERIA_TEXT, "bags": results}
    (args.out / "side_by_side.json").write_text(json.dumps(document, indent=1))
    if any("error" in r for r in results):
        return 1
    failed = any(r["failed_criteria"] for res in results for r in res["runs"] if r["failed_criteria"] is not None)
    return 1 if args.strict and failed else 0


if __name__ == "__main__":
    sys.exit(main())
