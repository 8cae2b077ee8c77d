#!/usr/bin/env python3
"""Reads the nvtmm state stream (live UDP or a recording) and prints frames.

Standard library only, written from docs/STREAM.md alone: proof that a
renderer can consume the stream from the format document.

    python3 tools/stream_client.py --listen 127.0.0.1:7878      # live
    python3 tools/stream_client.py --file run.nvts              # recording
    python3 tools/stream_client.py --file run.nvts --json       # one JSON object per message
"""

import argparse
import json
import math
import socket
import struct
import sys

MAGIC = b"NVTS"
VERSION = 3  # 3: state frames end with one polyline per instrument (id, kind, points)
VERSION_2 = 2  # 2: with the guidewire's polyline alone (still read)
MAX_INSTRUMENT_POINTS = 256
MAX_FRAME_INSTRUMENTS = 8
INSTRUMENT_KINDS = {1: "probe", 2: "guidewire", 3: "catheter"}
HEADER = struct.Struct("<4sHBBIIIIHH")  # 28 bytes
MAX_DATAGRAM = 1200
KIND_TOPOLOGY, KIND_STATE = 1, 2
STATE_FIXED = struct.Struct("<dII3ff3fff")  # 52 bytes
REC_MAGIC = b"NVTSREC\0"
REC_HEADER = struct.Struct("<8sHHIQ")  # 24 bytes
REC_ENTRY = struct.Struct("<QI")  # 12 bytes
FLAGS = ["watchdog", "contact", "limited", "rt", "refreshed", "simulated"]


class Reassembler:
    """Datagrams in any order -> complete, validated messages."""

    def __init__(self):
        self.partial = {}  # seq -> [header tuple, bytearray, {index: (offset, len)}]
        self.done = []  # recently completed seqs (duplicates)
        self.newest = None
        self.topology = None
        self.rejected = {}
        self.gaps = 0

    def reject(self, why):
        self.rejected[why] = self.rejected.get(why, 0) + 1

    def push(self, d):
        if len(d) > MAX_DATAGRAM:
            return self.reject("oversized")
        if len(d) <= HEADER.size:
            return self.reject("short")
        magic, ver, kind, _, seq, epoch, mlen, off, idx, count = HEADER.unpack_from(d)
        if magic != MAGIC:
            return self.reject("bad_magic")
        if ver not in (VERSION, VERSION_2):
            return self.reject("bad_version")
        if kind not in (KIND_TOPOLOGY, KIND_STATE):
            return self.reject("bad_kind")
        n = len(d) - HEADER.size
        if count == 0 or idx >= count or mlen == 0 or mlen > count * (MAX_DATAGRAM - HEADER.size) or off + n > mlen:
            return self.reject("bad_chunk")
        if seq in self.done:
            return None
        p = self.partial.get(seq)
        if p is None:
            p = self.partial[seq] = [(ver, kind, epoch, mlen, count), bytearray(mlen), {}]
            if len(self.partial) > 8:  # drop the oldest incomplete message
                del self.partial[max(self.partial, key=lambda s: (seq - s) % 2**32)]
        elif p[0] != (ver, kind, epoch, mlen, count):
            return self.reject("inconsistent")
        if idx in p[2]:
            return None
        p[1][off:off + n] = d[HEADER.size:]
        p[2][idx] = (off, n)
        if len(p[2]) < count:
            return None
        del self.partial[seq]
        self.done = (self.done + [seq])[-64:]
        expect = 0
        for k in range(count):
            o, ln = p[2][k]
            if o != expect:
                return self.reject("inconsistent")
            expect += ln
        if expect != mlen:
            return self.reject("inconsistent")
        if self.newest is not None:
            ahead = (seq - self.newest) % 2**32
            if 0 < ahead < 2**20:
                self.gaps += ahead - 1
                self.newest = seq
        else:
            self.newest = seq
        return self.message(ver, kind, seq, epoch, bytes(p[1]))

    @staticmethod
    def instruments(ver, b, o):
        """The polylines after the positions: [(id, kind, points)], or None if malformed."""
        (n,) = struct.unpack_from("<I", b, o)
        o += 4
        if ver == VERSION_2:  # the guidewire's polyline alone
            if n > MAX_INSTRUMENT_POINTS or len(b) != o + 12 * n:
                return None
            pts = [struct.unpack_from("<3f", b, o + 12 * i) for i in range(n)]
            return [(0, 2, pts)] if n else []
        if n > MAX_FRAME_INSTRUMENTS:
            return None
        out = []
        for _ in range(n):
            if len(b) < o + 4:
                return None
            iid, kind, w = struct.unpack_from("<BBH", b, o)
            o += 4
            if w > MAX_INSTRUMENT_POINTS or len(b) < o + 12 * w:
                return None
            out.append((iid, kind, [struct.unpack_from("<3f", b, o + 12 * i) for i in range(w)]))
            o += 12 * w
        return out if o == len(b) else None

    def message(self, ver, kind, seq, epoch, b):
        if kind == KIND_TOPOLOGY:
            nv, nt = struct.unpack_from("<II", b, 0)
            if len(b) != 8 + 16 * nv + 12 * nt:
                return self.reject("bad_payload")
            rest = [struct.unpack_from("<3f", b, 8 + 12 * i) for i in range(nv)]
            to = 8 + 12 * nv
            tris = [struct.unpack_from("<3I", b, to + 12 * k) for k in range(nt)]
            if any(i >= nv for t in tris for i in t):
                return self.reject("bad_payload")
            nodes = list(struct.unpack_from("<%dI" % nv, b, to + 12 * nt))
            self.topology = {"kind": "topology", "seq": seq, "epoch": epoch, "vertices": nv,
                             "triangles": nt, "rest": rest, "tris": tris, "node_ids": nodes}
            return self.topology
        if len(b) < STATE_FIXED.size:
            return self.reject("bad_payload")
        t, flags, nv, tx, ty, tz, radius, fx, fy, fz, rate, p99 = STATE_FIXED.unpack_from(b, 0)
        wo = STATE_FIXED.size + 12 * nv
        if len(b) < wo + 4:
            return self.reject("bad_payload")
        lines = self.instruments(ver, b, wo)
        if lines is None:
            return self.reject("bad_payload")
        pos = [struct.unpack_from("<3f", b, STATE_FIXED.size + 12 * i) for i in range(nv)]
        if not all(math.isfinite(v) for p in pos + [q for ln in lines for q in ln[2]] for v in p):
            return self.reject("bad_payload")
        if self.topology is None or self.topology["epoch"] != epoch:
            return None  # wait for the topology of this epoch
        if nv != self.topology["vertices"]:
            return self.reject("inconsistent")
        return {"kind": "state", "seq": seq, "epoch": epoch, "time_s": t, "flags": flags,
                "tool": [tx, ty, tz], "tool_radius": radius, "force": [fx, fy, fz],
                "loop_rate_hz": rate, "tick_p99_us": p99, "positions": pos,
                "instruments": [{"id": i, "kind": k, "points": pts} for i, k, pts in lines]}


def recording(path):
    with open(path, "rb") as f:
        h = f.read(REC_HEADER.size)
        if len(h) < REC_HEADER.size:
            sys.exit("%s: shorter than the recording header" % path)
        magic, ver, stream_ver, hlen, _start = REC_HEADER.unpack(h)
        if magic != REC_MAGIC or ver != 1:
            sys.exit("%s: not an nvtmm stream recording (version 1)" % path)
        f.read(hlen - REC_HEADER.size)
        while True:
            e = f.read(REC_ENTRY.size)
            if not e:
                return
            if len(e) < REC_ENTRY.size:
                sys.exit("%s: truncated record" % path)
            t_ns, n = REC_ENTRY.unpack(e)
            d = f.read(n)
            if len(d) < n:
                sys.exit("%s: truncated record" % path)
            yield t_ns, d


def live(addr):
    host, port = addr.rsplit(":", 1)
    s = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_DGRAM)
    s.bind((host.strip("[]"), int(port)))
    while True:
        d, _ = s.recvfrom(65536)
        yield None, d


def summary(m, topology):
    if m["kind"] == "topology":
        return {k: m[k] for k in ("kind", "seq", "epoch", "vertices", "triangles")}
    rest = topology["rest"]
    disp = max(math.dist(p, q) for p, q in zip(m["positions"], rest)) if rest else 0.0
    out = {k: m[k] for k in ("kind", "seq", "epoch", "time_s", "flags", "tool", "tool_radius", "force",
                             "loop_rate_hz", "tick_p99_us")}
    out["vertices"] = len(m["positions"])
    out["positions_sum"] = sum(v for p in m["positions"] for v in p)
    out["max_displacement"] = disp
    wire = next((i["points"] for i in m["instruments"] if i["kind"] == 2), [])
    out["wire_points"] = len(wire)
    out["wire_sum"] = sum(v for p in wire for v in p)
    out["instruments"] = [{"id": i["id"], "kind": i["kind"], "name": INSTRUMENT_KINDS.get(i["kind"], "kind %d" % i["kind"]),
                           "points": len(i["points"])} for i in m["instruments"]]
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--listen", metavar="HOST:PORT", help="receive live UDP")
    src.add_argument("--file", metavar="REC", help="read a recording")
    ap.add_argument("--json", action="store_true", help="one JSON object per message")
    ap.add_argument("--count", type=int, default=0, help="stop after this many state frames")
    a = ap.parse_args()
    r = Reassembler()
    states = 0
    try:
        for _, d in (recording(a.file) if a.file else live(a.listen)):
            m = r.push(d)
            if m is None:
                continue
            s = summary(m, r.topology)
            if a.json:
                print(json.dumps(s), flush=True)
            elif m["kind"] == "topology":
                print("topology epoch %d: %d vertices, %d triangles" % (s["epoch"], s["vertices"], s["triangles"]),
                      flush=True)
            else:
                f = s["force"]
                names = " ".join(n for i, n in enumerate(FLAGS) if s["flags"] >> i & 1) or "-"
                print("seq %6d  t %8.3f s  |F| %.3f N  tool (%.4f %.4f %.4f) m  max disp %.2f mm  [%s]" % (
                    s["seq"], s["time_s"], math.hypot(*f), *s["tool"], 1000 * s["max_displacement"], names),
                    flush=True)
            if m["kind"] == "state":
                states += 1
                if a.count and states >= a.count:
                    break
    except KeyboardInterrupt:
        pass
    if not a.json:
        print("gaps %d  rejected %s" % (r.gaps, r.rejected or 0), file=sys.stderr)
