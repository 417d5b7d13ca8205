#!/usr/bin/env python3
"""Forwards YUYV camera frames to relocd and asks it to relocalise: what a team's process does when it
owns the top camera (relocd's source `frames:unix:PATH`, docs/protocol.md "Forwarded frames").

    python3 relocd_send_frame.py --yuyv frame.yuyv --width 640 --height 480 \\
        --frames /tmp/relocd-frames --control unix:/tmp/relocd-control

Sends the frame at --fps for --seconds (a camera loop), asks for a relocalisation after the first
frame, and prints the accepted trigger id on stdout. A raw YUYV frame comes from the camera, or from
`relocd render --format yuyv`. Standard library only.
"""

import argparse
import os
import socket
import struct
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from relocd_client import Control, RelocdError  # noqa: E402  (the client beside this file)

HEADER = struct.Struct("<4sHHIIIId4f")  # 48 bytes, little-endian, no padding
FORMAT_YUYV = 1
FLAG_CAMERA_POSE = 1


def frame_header(width, height, timestamp, camera=None):
    """The 48-byte header; camera = (height m, pitch rad, roll rad, head yaw rad) or None."""
    flags = FLAG_CAMERA_POSE if camera else 0
    return HEADER.pack(b"RLF1", 1, FORMAT_YUYV, width, height, width * height * 2, flags, timestamp,
                       *(camera or (0.0, 0.0, 0.0, 0.0)))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--yuyv", required=True, help="raw packed YUYV frame file")
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--frames", default="/tmp/relocd-frames", help="relocd's frame socket path")
    parser.add_argument("--control", default="unix:/tmp/relocd-control", help="relocd's control socket")
    parser.add_argument("--camera", metavar="H,PITCH,ROLL,YAW",
                        help="camera pose (m, rad) from your kinematics; default: relocd's own guess")
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--seconds", type=float, default=2.0)
    args = parser.parse_args()

    with open(args.yuyv, "rb") as file:
        payload = file.read()
    if len(payload) != args.width * args.height * 2:
        sys.exit(f"error: {args.yuyv} has {len(payload)} bytes, a {args.width}x{args.height} YUYV frame "
                 f"has {args.width * args.height * 2}")
    camera = tuple(float(v) for v in args.camera.split(",")) if args.camera else None
    if camera is not None and len(camera) != 4:
        sys.exit("error: --camera needs four numbers: height,pitch,roll,head_yaw")

    if not 0 < args.fps <= 60:
        sys.exit("error: --fps must lie in (0, 60]")

    frames = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    control = None
    trigger = None
    try:
        frames.connect(args.frames)
        control = Control(args.control)
        end = time.monotonic() + args.seconds
        while time.monotonic() < end:
            frames.sendall(frame_header(args.width, args.height, time.time(), camera) + payload)
            if trigger is None:
                trigger = control.relocalise(reason="forwarded frame example")
                print(trigger, flush=True)
            time.sleep(1.0 / args.fps)
    except (OSError, RelocdError, TimeoutError) as error:
        sys.exit(f"error: {error}")
    finally:
        if control is not None:
            control.close()
        frames.close()


if __name__ == "__main__":
    main()
