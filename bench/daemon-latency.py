#!/usr/bin/env python3
"""Trigger to published message, from the daemon's own latency breakdown, and the daemon's peak RSS.

    python3 bench/daemon-latency.py [--relocd BINARY] [--burst 1] [--requests 12] [--skip 2] [-- RUN_ARGS...]

Starts `relocd run --source replay:tests/data/sample` (640x480 JPEG frames at 30 fps, looping) with a
loopback control socket and publish target, sends `--requests` relocalise requests 1.2 s apart (past the
default one-burst-per-second rate limit, so no request waits for another), drops the first `--skip`
answers (warm-up) and prints the median of each `latency_ms` stage. After SIGTERM it prints the daemon's
peak resident set size (getrusage of the child). Extra arguments after `--` go to `relocd run` (e.g.
`--backend onnxruntime`). Uses examples/relocd_client.py.
"""

import argparse
import json
import os
import resource
import socket
import statistics
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "examples"))
from relocd_client import Control, Subscriber  # noqa: E402

STAGES = ["wait", "capture", "preprocess", "inference", "fusion", "refine", "total"]


def free_udp_port():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--relocd", default=os.path.join(
        os.environ.get("CARGO_TARGET_DIR", os.path.join(ROOT, "target")), "release", "relocd"))
    parser.add_argument("--burst", type=int, default=1, help="frames per burst")
    parser.add_argument("--requests", type=int, default=12)
    parser.add_argument("--skip", type=int, default=2, help="answers dropped as warm-up")
    parser.add_argument("run_args", nargs="*", help="more `relocd run` arguments (after --)")
    args = parser.parse_args()
    if args.requests <= args.skip:
        sys.exit("error: --requests must be larger than --skip")

    control_port, publish_port = free_udp_port(), free_udp_port()
    subscriber = Subscriber(f"udp:127.0.0.1:{publish_port}")
    config = os.path.join(os.environ.get("TMPDIR", "/tmp"), f"relocd-latency-{os.getpid()}.toml")
    with open(config, "w") as file:
        file.write(f'[publish]\ntargets = ["udp:127.0.0.1:{publish_port}"]\n')
    daemon = subprocess.Popen(
        [args.relocd, "run", "--config", config, "--source", f"replay:{ROOT}/tests/data/sample",
         "--control", f"udp:127.0.0.1:{control_port}", "--sensors", "off", "--burst", str(args.burst),
         *args.run_args],
        stderr=subprocess.DEVNULL)
    try:
        time.sleep(1.0)
        control = Control(f"udp:127.0.0.1:{control_port}", timeout=5.0)
        latencies = []
        for request in range(args.requests):
            trigger = control.relocalise(reason="bench")
            message = subscriber.receive_answer(trigger, timeout=10.0)
            if message.failure:
                sys.exit(f"error: trigger {trigger} failed: {message.failure}")
            if request >= args.skip:
                latencies.append(message.raw["latency_ms"])
            time.sleep(1.2)
        control.close()
    finally:
        daemon.terminate()
        daemon.wait(timeout=10)
        os.remove(config)
        subscriber.close()
    peak_kib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    medians = {stage: statistics.median(entry[stage] for entry in latencies) for stage in STAGES}
    print(json.dumps({"burst": args.burst, "answers": len(latencies), "median_latency_ms": medians,
                      "peak_rss_kib": peak_kib}))


if __name__ == "__main__":
    main()
