#!/usr/bin/env python3
"""Reference peer for nvtmm's UDP device bridge (src/haptics/udp.rs).

Plays a scripted pose (a circle in the device's x-y plane, SI units, with
the stylus rolling at a steady rate) at a fixed rate to the service, and
prints the force datagrams it gets back.
Standard library only. A real peer would read the pose from the vendor
driver instead of the script and command the force it receives.

Datagram layouts (little-endian) are in docs/DEVICE.md:
  pose v1 (84 bytes): b"NVTP", u16 version, u16 reserved, u64 seq, f64 device
                    time (s), 3 f64 position (m), 3 f64 velocity (m/s),
                    u32 buttons, u32 status, i32 vendor error code
  pose v2 (108 bytes): v1 (version 2), then 3 f64 gimbal angles (rad, the
                    stylus roll last), as HD_CURRENT_GIMBAL_ANGLES gives them
  force (56 bytes): b"NVTF", u16 version, u16 reserved, u64 seq, u64 echoed
                    pose seq, 3 f64 force (N), u32 flags, u32 reserved

Example:
  python3 tools/udp_device_peer.py --service 127.0.0.1:47010 --seconds 2
"""

import argparse
import math
import socket
import struct
import sys
import time

POSE = struct.Struct("<4sHHQd3d3dIIi")
POSE_V2 = struct.Struct("<4sHHQd3d3dIIi3d")
FORCE = struct.Struct("<4sHHQQ3dII")
VERSION = 1
assert POSE.size == 84 and POSE_V2.size == 108 and FORCE.size == 56


def addr(text):
    host, _, port = text.rpartition(":")
    return host, int(port)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--service", default="127.0.0.1:47010", help="service bind address (IP:port)")
    ap.add_argument("--bind", default="127.0.0.1:0", help="local address for this peer (IP:port)")
    ap.add_argument("--rate", type=float, default=1000.0, help="pose rate (Hz)")
    ap.add_argument("--seconds", type=float, default=2.0, help="how long to play")
    ap.add_argument("--radius", type=float, default=0.02, help="circle radius (m)")
    ap.add_argument("--period", type=float, default=1.0, help="circle period (s)")
    ap.add_argument("--roll-rate", type=float, default=1.0, help="stylus roll rate (rad/s)")
    ap.add_argument("--pose-version", type=int, choices=(1, 2), default=2, help="1: no gimbal angles")
    ap.add_argument("--print-every", type=int, default=100, help="print every n-th force")
    a = ap.parse_args()

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(addr(a.bind))
    sock.setblocking(False)
    service = addr(a.service)

    dt = 1.0 / a.rate
    t0 = time.monotonic()
    seq = 0
    forces = 0
    bad = 0
    w = 2.0 * math.pi / a.period
    next_t = t0
    while True:
        now = time.monotonic()
        t = now - t0
        if t > a.seconds:
            break
        seq += 1
        pos = (a.radius * math.cos(w * t), a.radius * math.sin(w * t), 0.0)
        vel = (-a.radius * w * math.sin(w * t), a.radius * w * math.cos(w * t), 0.0)
        if a.pose_version == 2:
            # The roll as a device reports it: wrapped to (-pi, pi].
            roll = math.remainder(a.roll_rate * t, 2.0 * math.pi)
            pose = POSE_V2.pack(b"NVTP", 2, 0, seq, t, *pos, *vel, 0, 0, 0, 0.0, 0.0, roll)
        else:
            pose = POSE.pack(b"NVTP", VERSION, 0, seq, t, *pos, *vel, 0, 0, 0)
        sock.sendto(pose, service)
        while True:
            try:
                data, _ = sock.recvfrom(256)
            except BlockingIOError:
                break
            except ConnectionRefusedError:
                break  # the service is not up yet
            if len(data) != FORCE.size:
                bad += 1
                continue
            magic, ver, _, fseq, pseq, fx, fy, fz, flags, _ = FORCE.unpack(data)
            if magic != b"NVTF" or ver != VERSION:
                bad += 1
                continue
            forces += 1
            if forces % a.print_every == 1 or flags & 2:
                print(f"force seq {fseq} for pose {pseq}: [{fx:+.4f}, {fy:+.4f}, {fz:+.4f}] N flags {flags:#x}")
        next_t += dt
        delay = next_t - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    print(f"sent {seq} poses, received {forces} forces, {bad} bad datagrams", file=sys.stderr)


if __name__ == "__main__":
    main()
