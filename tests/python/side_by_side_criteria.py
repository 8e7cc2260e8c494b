#!/usr/bin/env python3
"""Checks the side-by-side benchmark's tiers and verdicts (scripts/side_by_side_report.py) on
hand-made summaries; prints "ok" and exits 0, or fails an assertion. Run by tests/side_by_side.rs."""
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2] / "scripts"))
import side_by_side_report as r  # noqa: E402


def summary(rr, mre=1.0, mte=0.02, ms=5.0):
    return {"frames": 20, "RR": rr, "MRE": mre, "MTE": mte, "median_ms": ms}


def main():
    assert r.tier_of("redkitchen-extreme-val-harsh") == r.Tier("extreme", True)
    assert r.tier_of("redkitchen-hard-val-disparity") == r.Tier("hard", True)
    assert r.tier_of("redkitchen-sift-val") == r.Tier("sift", False)
    assert r.tier_of("synth-hard") == r.Tier("hard", False)
    assert r.tier_of("synth-building") == r.Tier("hard", False)
    assert r.tier_of("building+harsh") == r.Tier("hard", False)
    assert r.tier_of("building-disparity") == r.Tier("hard", True)
    assert r.tier_of("office-seq") is None
    poselib = summary(95.0, mre=3.0, mte=0.08, ms=18.0)
    hard = r.Tier("hard", False)
    assert r.criteria_failures(hard, summary(100.0, ms=9.0), poselib) == []
    assert r.criteria_failures(hard, summary(95.0, ms=9.0), poselib) == ["RR 95.0 < 100"]
    assert r.criteria_failures(hard, summary(100.0, ms=9.1), poselib) == ["time x0.51 > 0.5"]
    assert r.criteria_failures(hard, summary(100.0, mre=3.1, mte=0.5, ms=2.0), poselib) == ["MRE 3.100 > PoseLib 3.000"]
    sift = r.Tier("sift", False)
    assert r.criteria_failures(sift, summary(100.0, mte=0.09, ms=2.0), poselib) == ["MTE 0.0900 > PoseLib 0.0800"]
    # Extreme: an absolute bar with the shared prior, PoseLib + 15 points with a realistic one.
    assert r.criteria_failures(r.Tier("extreme", False), summary(90.0, mre=40, ms=2.0), summary(25.0)) == []
    assert r.criteria_failures(r.Tier("extreme", False), summary(88.3, ms=2.0), summary(25.0)) == ["RR 88.3 < 90"]
    realistic = r.Tier("extreme", True)
    assert r.criteria_failures(realistic, summary(40.0, ms=2.0), summary(25.0)) == []
    assert r.criteria_failures(realistic, summary(39.0, ms=2.0), summary(25.0)) == ["RR 39.0 < PoseLib 25.0 + 15"]
    # Either bar is capped at the single-frame oracle's RR - 5 where that is lower (baseline.json
    # rounds 53/60 to 88.333).
    assert r.criteria_failures(r.Tier("extreme", False), summary(100 * 50 / 60, ms=2.0), summary(25.0), 88.333) == []
    assert r.criteria_failures(r.Tier("extreme", False), summary(80.0, ms=2.0), summary(25.0), 88.333) == \
        ["RR 80.0 < oracle 88.3 - 5"]
    assert r.criteria_failures(r.Tier("extreme", False), summary(88.3, ms=2.0), summary(25.0), 100.0) == ["RR 88.3 < 90"]
    assert r.criteria_failures(realistic, summary(39.0, ms=2.0), summary(25.0), 88.333) == \
        ["RR 39.0 < PoseLib 25.0 + 15"]
    assert r.criteria_failures(realistic, summary(40.0, ms=2.0), summary(30.0), 42.0) == []
    # A published pose is a promise: more than 5 % wrong ones fails any tier (issue 34).
    extreme_fp = {**summary(90.0, ms=2.0), "false_pose_rate": 10.0}
    assert r.criteria_failures(r.Tier("extreme", False), extreme_fp, summary(25.0)) == ["false poses 10.0 % > 5 %"]
    assert r.criteria_failures(hard, {**summary(100.0, ms=9.0), "false_pose_rate": 0.0}, poselib) == []
    # No pose at all is the worst error; PoseLib without a time cannot be compared.
    assert r.criteria_failures(hard, summary(100.0, mre=None, ms=2.0), poselib) == ["MRE – > PoseLib 3.000"]
    assert r.criteria_failures(hard, summary(100.0, ms=2.0), summary(0.0, mre=None, ms=None)) == ["no time to compare"]
    assert r.criteria_failures(None, summary(0.0), poselib) is None
    frames = [{"has_pose": False, "failure": "PnP failed: best pose has 5 inliers, 6 required"},
              {"has_pose": False, "failure": "PnP failed: best pose has 4 inliers, 6 required"},
              {"has_pose": False, "failure": None}, {"has_pose": True, "failure": None}]
    assert r.failure_counts(frames) == {"PnP failed: best pose has # inliers, # required": 2, "no pose": 1}
    run = {"label": "x", "frames": [{**f, "registered": f["has_pose"] and i == 3} for i, f in enumerate(frames)]}
    assert r.misses_line(run) is not None and "misses 3 frames" in r.misses_line(run)
    run["frames"].append({"has_pose": True, "registered": False, "failure": None})
    assert "misses 4 frames: 1 with a wrong pose" in r.misses_line(run), r.misses_line(run)
    assert r.misses_line({"label": "x", "frames": [{"has_pose": True, "registered": True, "failure": None}]}) is None
    print("ok")


if __name__ == "__main__":
    main()
