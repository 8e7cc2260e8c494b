"""Reading localization bags with rosbags and scoring poses as `angle-i2p eval` does.

The metric definitions are those of src/eval/mod.rs (and of the reference evaluator it is tested
against): a frame is registered when the RMSE, over its ground-truth-depth points (every 4th
pixel), between the points moved by the true and by the estimated camera-to-map pose is below
0.1 m; MRE / MTE are mean rotation (degrees) and translation (metres) errors over the frames
with a pose. Nothing here imports from ../shared, which a user's checkout does not have.
"""
from __future__ import annotations

import dataclasses
import pathlib

import numpy as np
from rosbags.highlevel import AnyReader

RECALL_THRESHOLD_M = 0.1
RMSE_STRIDE = 4
STATUS_NAME = "angle_i2p: localization"  # the per-frame status replay writes (src/app.rs)
DIAGNOSTICS_TOPIC = "/diagnostics"


@dataclasses.dataclass
class Camera:
    k: np.ndarray  # 3x3
    width: int
    height: int


@dataclasses.dataclass
class InputFrame:
    """One input frame: what PoseLib needs and the ground truth the metrics need."""
    stamp: int
    camera: Camera | None = None
    correspondences: np.ndarray | None = None  # N x 6: u, v, x, y, z, score
    gt_pose: np.ndarray | None = None  # 4x4 camera-to-map
    gt_depth: np.ndarray | None = None  # metres, 0 = unknown

    def scorable(self) -> bool:
        return self.camera is not None and self.gt_pose is not None and self.gt_depth is not None


@dataclasses.dataclass
class OutputFrame:
    """What a replay's output bag says about one frame."""
    pose: np.ndarray | None = None
    ms: float | None = None
    failure: str | None = None
    kept: int | None = None
    pnp_inliers: int | None = None


@dataclasses.dataclass
class PoseError:
    rotation_deg: float
    translation_m: float
    rmse_m: float

    @property
    def registered(self) -> bool:
        return self.rmse_m < RECALL_THRESHOLD_M


def stamp_ns(header) -> int:
    return int(header.stamp.sec) * 10**9 + int(header.stamp.nanosec)


def quaternion_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    q = np.array([w, x, y, z], dtype=np.float64)
    norm = np.linalg.norm(q)
    if not np.isfinite(norm) or norm < 1e-12:
        raise ValueError(f"degenerate quaternion ({x}, {y}, {z}, {w})")
    w, x, y, z = q / norm
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def pose_matrix(pose) -> np.ndarray:
    t = np.eye(4)
    q = pose.orientation
    t[:3, :3] = quaternion_matrix(q.x, q.y, q.z, q.w)
    t[:3, 3] = [pose.position.x, pose.position.y, pose.position.z]
    return t


def depth_metres(image) -> np.ndarray:
    """A sensor_msgs/Image depth as metres: 16UC1 millimetres or 32FC1 metres; honours step and endianness."""
    kinds = {"16UC1": (np.uint16, 1e-3), "32FC1": (np.float32, 1.0)}
    if image.encoding not in kinds:
        raise ValueError(f"depth encoding {image.encoding!r} (expected 16UC1 or 32FC1)")
    kind, scale = kinds[image.encoding]
    dtype = np.dtype(kind).newbyteorder(">" if image.is_bigendian else "<")
    h, w, step = int(image.height), int(image.width), int(image.step)
    data = bytes(image.data)
    if step < w * dtype.itemsize or len(data) < h * step:
        raise ValueError(f"depth image {w}x{h}, step {step}: {len(data)} bytes is too short")
    rows = np.frombuffer(data[: h * step], np.uint8).reshape(h, step)[:, : w * dtype.itemsize]
    return np.ascontiguousarray(rows).view(dtype).reshape(h, w).astype(np.float64) * scale


def correspondence_array(msg) -> np.ndarray:
    rows = [[c.u, c.v, c.x, c.y, c.z, c.score] for c in msg.correspondences]
    return np.array(rows, dtype=np.float64).reshape(-1, 6)


def read_input(bag: pathlib.Path, topics: dict) -> tuple[dict[int, InputFrame], list[str]]:
    """Frames of an input bag by stamp, and the messages that could not be read (topic, stamp, reason)."""
    frames: dict[int, InputFrame] = {}
    issues: list[str] = []
    wanted = {topics["camera_info"]: "camera", topics["correspondences"]: "correspondences",
              topics["ground_truth_pose"]: "gt_pose", topics["ground_truth_depth"]: "gt_depth"}
    with AnyReader([bag]) as reader:
        connections = [c for c in reader.connections if c.topic in wanted]
        for conn, log_time, raw in reader.messages(connections=connections):
            try:
                msg = reader.deserialize(raw, conn.msgtype)
                frame = frames.setdefault(stamp_ns(msg.header), InputFrame(stamp_ns(msg.header)))
                role = wanted[conn.topic]
                if role == "camera":
                    frame.camera = Camera(np.array(msg.k, dtype=np.float64).reshape(3, 3), int(msg.width), int(msg.height))
                elif role == "correspondences":
                    frame.correspondences = correspondence_array(msg)
                elif role == "gt_pose":
                    frame.gt_pose = pose_matrix(msg.pose)
                else:
                    frame.gt_depth = depth_metres(msg)
            except Exception as e:  # noqa: BLE001 — one unreadable message skips that part of its frame, named
                issues.append(f"{conn.topic} at log time {log_time}: {e}")
    return frames, issues


def diagnostics_values(status) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def read_output(bag: pathlib.Path, pose_topic: str) -> dict[int, OutputFrame]:
    """Per stamp: the pose, total ms, failure reason, kept and PnP inliers a replay wrote."""
    out: dict[int, OutputFrame] = {}
    with AnyReader([bag]) as reader:
        connections = [c for c in reader.connections if c.topic in (pose_topic, DIAGNOSTICS_TOPIC)]
        for conn, _, raw in reader.messages(connections=connections):
            msg = reader.deserialize(raw, conn.msgtype)
            frame = out.setdefault(stamp_ns(msg.header), OutputFrame())
            if conn.topic == pose_topic:
                frame.pose = pose_matrix(msg.pose)
                continue
            for status in (s for s in msg.status if s.name == STATUS_NAME):
                values = diagnostics_values(status)
                frame.failure = None if status.message == "localized" else status.message
                frame.ms = float(values["total_ms"]) if "total_ms" in values else None
                frame.kept = int(values["kept"]) if "kept" in values else None
                frame.pnp_inliers = int(values["pnp_inliers"]) if "pnp_inliers" in values else None
    return out


def pose_error(est: np.ndarray, gt: np.ndarray, k: np.ndarray, depth: np.ndarray) -> PoseError:
    """Rotation, translation and ground-truth-depth-point RMSE of a camera-to-map estimate."""
    d_r = est[:3, :3].T @ gt[:3, :3]
    rotation = float(np.degrees(np.arccos(np.clip((np.trace(d_r) - 1) / 2, -1, 1))))
    d_t = gt[:3, 3] - est[:3, 3]
    sample = depth[::RMSE_STRIDE, ::RMSE_STRIDE]
    v, u = np.nonzero((sample != 0) & np.isfinite(sample))
    z = sample[v, u]
    u, v = u * RMSE_STRIDE, v * RMSE_STRIDE
    points = np.stack([(u - k[0, 2]) * z / k[0, 0], (v - k[1, 2]) * z / k[1, 1], z], 1)
    diff = points @ (gt[:3, :3] - est[:3, :3]).T + d_t
    rmse = float(np.sqrt((diff ** 2).sum(1).mean())) if len(z) else float("nan")
    return PoseError(rotation, float(np.linalg.norm(d_t)), rmse)


def frame_row(frame: InputFrame, pose: np.ndarray | None, ms: float | None, failure: str | None, **extra) -> dict:
    """One scored frame as JSON-ready data."""
    err = pose_error(pose, frame.gt_pose, frame.camera.k, frame.gt_depth) if pose is not None else None
    row = {"stamp": frame.stamp, "has_pose": err is not None, "registered": bool(err and err.registered),
           "rotation_deg": err.rotation_deg if err else None, "translation_m": err.translation_m if err else None,
           "rmse_m": err.rmse_m if err else None, "ms": ms, "failure": failure}
    row.update(extra)
    return row


def summarize(rows: list[dict]) -> dict:
    """RR %, availability and false-pose rate %, MRE, MTE (means over frames with a pose), medians, and median /
    mean ms, as eval's JSON names them."""
    with_pose = [r for r in rows if r["has_pose"]]
    times = [r["ms"] for r in rows if r["ms"] is not None]

    def stat(fn, values):
        return float(fn(values)) if values else None

    wrong = sum(not r["registered"] for r in with_pose)
    return {"frames": len(rows),
            "RR": 100.0 * sum(r["registered"] for r in rows) / max(1, len(rows)),
            "availability": 100.0 * len(with_pose) / max(1, len(rows)),
            "false_pose_rate": 100.0 * wrong / len(with_pose) if with_pose else None,
            "MRE": stat(np.mean, [r["rotation_deg"] for r in with_pose]),
            "MTE": stat(np.mean, [r["translation_m"] for r in with_pose]),
            "MedRE": stat(np.median, [r["rotation_deg"] for r in with_pose]),
            "MedTE": stat(np.median, [r["translation_m"] for r in with_pose]),
            "median_ms": stat(np.median, times), "ms_per_frame": stat(np.mean, times)}
