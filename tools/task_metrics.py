#!/usr/bin/env python3
"""Task metrics recomputed from a stream recording, independently of the
service's Rust code (docs/DRIVING.md "Metrics (definitions)").

The recording carries each state frame's time, the force rendered to the
hand and the wire's polyline; from them this script computes the figures
that depend on those alone: time to target, the tip's path length, the
inserted length, pull-backs and the hub force's peak. The wall contact force
and the device buttons are not in the stream.

  python3 tools/task_metrics.py --file run.nvts --wall wall.json --target left_subclavian

`wall.json`: {"points": [[x, y, z], ...], "labels": [i, ...], "names": [...]},
the labelled inner-wall vertices at rest (a point's segment is the label of
the nearest one). Prints one JSON object. Python standard library only.
"""
import argparse
import json
import math
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import stream_client  # noqa: E402  (the reference decoder of docs/STREAM.md)

PULLBACK_M = 5e-3


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--file", required=True, help="stream recording (.nvts)")
    ap.add_argument("--wall", required=True, help="labelled wall vertices (JSON)")
    ap.add_argument("--target", required=True, help="target segment label")
    ap.add_argument("--inside", type=float, default=0.02, help="required depth in the target (m)")
    a = ap.parse_args()
    with open(a.wall) as f:
        wall = json.load(f)
    pts, labels, names = wall["points"], wall["labels"], wall["names"]
    target = names.index(a.target)

    def label_at(p):
        best, lab = float("inf"), None
        for q, l in zip(pts, labels):
            d = (q[0] - p[0]) ** 2 + (q[1] - p[1]) ** 2 + (q[2] - p[2]) ** 2
            if d < best:
                best, lab = d, l
        return lab

    def depth(line):
        d, prev = 0.0, None
        for p in reversed(line):
            if label_at(p) != target:
                break
            if prev is not None:
                d += math.dist(p, prev)
            prev = p
            if d >= a.inside:
                break
        return d

    r = stream_client.Reassembler()
    t0 = None
    out = {"samples": 0, "tip_path_m": 0.0, "pullbacks": 0, "hub_force_peak_n": 0.0,
           "success": False, "time_to_target_s": None, "elapsed_s": 0.0, "inserted_m": 0.0}
    last_tip, peak, trough = None, 0.0, None
    for _, d in stream_client.recording(a.file):
        m = r.push(d)
        if not m or m["kind"] != "state":
            continue
        t = m["time_s"]
        if t0 is None:
            t0 = t
        out["samples"] += 1
        out["elapsed_s"] = t - t0
        out["hub_force_peak_n"] = max(out["hub_force_peak_n"], math.sqrt(sum(v * v for v in m["force"])))
        # The first guidewire on the stream (kind 2).
        line = next((i["points"] for i in m["instruments"] if i["kind"] == 2), [])
        if not line:
            continue
        tip = line[-1]
        if last_tip is not None:
            out["tip_path_m"] += math.dist(tip, last_tip)
        last_tip = tip
        ins = sum(math.dist(line[k], line[k + 1]) for k in range(len(line) - 1))
        out["inserted_m"] = ins
        # A pull-back: 5 mm below the peak since the wire last advanced; it
        # ends when the wire advances 5 mm above its low point since.
        if trough is None:
            peak = max(peak, ins)
            if ins <= peak - PULLBACK_M:
                out["pullbacks"] += 1
                trough = ins
        else:
            trough = min(trough, ins)
            if ins >= trough + PULLBACK_M:
                trough = None
                peak = ins
        if not out["success"] and depth(line) >= a.inside:
            out["success"] = True
            out["time_to_target_s"] = t - t0
    print(json.dumps(out))


if __name__ == "__main__":
    main()
