"""The side-by-side benchmark's verdicts and tables: a bag's tier, the acceptance criteria of
issues 9 and 34 checked against PoseLib's row, and the markdown table printed per bag."""
from __future__ import annotations

import collections
import dataclasses
import re

CRITERIA_TEXT = {
    "sift": "RR 100 %, MRE and MTE <= PoseLib's, false poses <= 5 %, median ms <= 1/2 PoseLib's",
    "hard": "RR 100 %, MRE <= PoseLib's, false poses <= 5 %, median ms <= 1/2 PoseLib's",
    "extreme": "RR >= 90 % with the shared prior, >= PoseLib's + 15 points with a realistic prior "
               "(-harsh, -disparity), either capped at the single-frame oracle's RR - 5 where the bag's "
               "baseline.json has one, false poses <= 5 %, median ms <= 1/2 PoseLib's",
}
REALISTIC_PRIOR_SUFFIXES = ("-harsh", "-disparity")
EXTREME_SHARED_PRIOR_RR = 90.0
EXTREME_REALISTIC_MARGIN = 15.0
# Issue 34: an extreme-tier bar is capped this far below the single-frame oracle's RR (RANSAC on the
# true inliers alone, `baseline.json`), where the oracle itself is lower: no frame-by-frame
# method registers what the oracle cannot.
ORACLE_MARGIN = 5.0
MAX_TIME_RATIO = 0.5
MAX_FALSE_POSE_RATE = 5.0  # % of the published poses that are wrong (issue 34): on every tier
RR_EPSILON = 1e-9  # RR is 100·k/n: compared with a tolerance of float rounding
ORACLE_ROUNDING = 1e-3  # baseline.json writes RR with 3 decimals (88.333 for 53/60)


@dataclasses.dataclass
class Tier:
    name: str  # sift, hard or extreme
    realistic_prior: bool  # the bag's name ends in -harsh or -disparity

    def describe(self) -> str:
        return f"{self.name} tier, {'realistic' if self.realistic_prior else 'shared'} prior"


# Synthetic presets whose name is not a tier but whose matches are one: `synth --preset building`
# (`building+harsh`, …) is the hard tier's matcher in a building, whether its bag is named
# `synth-building…` (side_by_side.py --synth) or after the preset alone.
TIER_OF_PRESET = {"synth-building": "hard", "building": "hard"}


def tier_of(name: str) -> Tier | None:
    """The tier named in a bag's name (extreme before hard before sift), or that of a preset
    named for its scene (TIER_OF_PRESET), or None."""
    lowered = name.lower()
    realistic = lowered.endswith(REALISTIC_PRIOR_SUFFIXES)
    for tier in ("extreme", "hard", "sift"):
        if tier in lowered:
            return Tier(tier, realistic)
    for preset, tier in TIER_OF_PRESET.items():
        if lowered.startswith(preset):
            return Tier(tier, realistic)
    return None


def time_ratio(summary: dict, poselib: dict) -> float | None:
    ours, theirs = summary.get("median_ms"), poselib.get("median_ms")
    return ours / theirs if ours is not None and theirs else None


def at_most(ours: float | None, theirs: float | None) -> bool:
    """ours <= theirs, where no value (no frame with a pose) is worst."""
    if ours is None:
        return theirs is None
    return theirs is None or ours <= theirs


def extreme_bar(tier: Tier, poselib_rr: float, oracle_rr: float | None) -> tuple[float, str]:
    """The extreme tier's RR bar and how it reads: 90 % with the shared prior, PoseLib's + 15 points
    with a realistic one, either capped at the oracle's RR - 5 where that is lower."""
    if tier.realistic_prior:
        bar, text = poselib_rr + EXTREME_REALISTIC_MARGIN, f"PoseLib {poselib_rr:.1f} + {EXTREME_REALISTIC_MARGIN:.0f}"
    else:
        bar, text = EXTREME_SHARED_PRIOR_RR, f"{EXTREME_SHARED_PRIOR_RR:.0f}"
    if oracle_rr is not None and oracle_rr - ORACLE_MARGIN < bar:
        bar, text = oracle_rr - ORACLE_MARGIN, f"oracle {oracle_rr:.1f} - {ORACLE_MARGIN:.0f}"
    return bar, text


def criteria_failures(tier: Tier | None, summary: dict, poselib: dict,
                      oracle_rr: float | None = None) -> list[str] | None:
    """The criteria of the bag's tier that a row misses (empty: PASS), or None for a bag of no tier.
    `oracle_rr`: the single-frame oracle's RR on the bag, where known (baseline.json)."""
    if tier is None:
        return None
    failed = []
    rr, pl_rr = summary["RR"], poselib["RR"]
    if tier.name in ("sift", "hard") and rr < 100.0 - RR_EPSILON:
        failed.append(f"RR {rr:.1f} < 100")
    if tier.name == "extreme":
        bar, text = extreme_bar(tier, pl_rr, oracle_rr)
        if rr < bar - ORACLE_ROUNDING:
            failed.append(f"RR {rr:.1f} < {text}")
    if tier.name in ("sift", "hard") and not at_most(summary.get("MRE"), poselib.get("MRE")):
        failed.append(f"MRE {number(summary.get('MRE'), 3)} > PoseLib {number(poselib.get('MRE'), 3)}")
    if tier.name == "sift" and not at_most(summary.get("MTE"), poselib.get("MTE")):
        failed.append(f"MTE {number(summary.get('MTE'), 4)} > PoseLib {number(poselib.get('MTE'), 4)}")
    false_poses = summary.get("false_pose_rate")
    if false_poses is not None and false_poses > MAX_FALSE_POSE_RATE + RR_EPSILON:
        failed.append(f"false poses {false_poses:.1f} % > {MAX_FALSE_POSE_RATE:.0f} %")
    ratio = time_ratio(summary, poselib)
    if ratio is None:
        failed.append("no time to compare")
    elif ratio > MAX_TIME_RATIO:
        failed.append(f"time x{ratio:.2f} > {MAX_TIME_RATIO}")
    return failed


def number(v: float | None, digits: int) -> str:
    return "–" if v is None else f"{v:.{digits}f}"


def verdict(failed: list[str] | None) -> str:
    if failed is None:
        return "– (no tier in the bag's name)"
    return "PASS" if not failed else "FAIL: " + "; ".join(failed)


def failure_counts(frames: list[dict]) -> collections.Counter:
    """Frames without a pose, by reason with its numbers as # (a pose is no failure, even when it is not registered)."""
    return collections.Counter(re.sub(r"\d+(\.\d+)?", "#", f["failure"] or "no pose")
                               for f in frames if not f["has_pose"])


def misses_line(run: dict) -> str | None:
    """The frames a row did not register: how many have a wrong pose, and why the others have none."""
    wrong = sum(1 for f in run["frames"] if f["has_pose"] and not f["registered"])
    reasons = failure_counts(run["frames"])
    if not wrong and not reasons:
        return None
    parts = [f"{wrong} with a wrong pose (RMSE >= 0.1 m)"] if wrong else []
    if reasons:
        parts.append(f"{sum(reasons.values())} without a pose: "
                     + "; ".join(f"{reason} ({n})" for reason, n in reasons.most_common(3))
                     + ("; …" if len(reasons) > 3 else ""))
    missed = wrong + sum(reasons.values())
    return f"\n{run['label']} misses {missed} frame{'s' if missed > 1 else ''}: " + "; ".join(parts) + "."


def markdown_table(result: dict) -> str:
    """One bag's table: a row per replayed method, then PoseLib's."""
    tier = Tier(**result["tier"]) if result["tier"] else None
    poselib = result["poselib"]["summary"]
    frames = poselib["frames"]
    rounds = poselib.get("timing_rounds", 1)
    timing = f"; times: per-frame median of {rounds} rounds" if rounds > 1 else ""
    lines = [f"### {result['name']} ({tier.describe() if tier else 'no tier'}; {frames} frames{timing})", "",
             "| method | RR % | false poses % | MRE ° | MTE m | median ms | time / PoseLib | verdict |",
             "|---|---|---|---|---|---|---|---|"]
    for r in result["runs"]:
        s = r["summary"]
        lines.append(f"| {r['label']} | {s['RR']:.1f} | {number(s.get('false_pose_rate'), 1)} | "
                     f"{number(s.get('MRE'), 3)} | {number(s.get('MTE'), 4)} | "
                     f"{number(s.get('median_ms'), 2)} | {number(time_ratio(s, poselib), 2)} | "
                     f"{verdict(r['failed_criteria'])} |")
    lines.append(f"| {result['poselib']['label']} | {poselib['RR']:.1f} | "
                 f"{number(poselib.get('false_pose_rate'), 1)} | {number(poselib.get('MRE'), 3)} | "
                 f"{number(poselib.get('MTE'), 4)} | {number(poselib.get('median_ms'), 2)} | 1.00 | – |")
    lines += [line for r in [*result["runs"], result["poselib"]] if (line := misses_line(r))]
    if result["read_issues"]:
        lines.append(f"\n{len(result['read_issues'])} input messages could not be read, e.g. {result['read_issues'][0]}.")
    mismatched = [r["label"] for r in result["runs"] if r["summary"].get("frames") != frames]
    if mismatched:
        lines.append(f"\nNote: eval scored a different number of frames than PoseLib for {', '.join(mismatched)}.")
    if tier:
        lines.append(f"\nCriteria ({tier.name}): {CRITERIA_TEXT[tier.name]}.")
    return "\n".join(lines) + "\n"
