#!/usr/bin/env bash
# Soak test (not in CI): runs the daemon for MINUTES (default 60) on the sample recording with a trigger
# every 2 s from alternating sources (control requests, GameController penalty returns) and garbage
# interleaved on every input, then checks that every trigger was answered, that peak RSS grew by less
# than 5% after a warm-up minute, and that no file descriptor or thread leaked.
#
#   tests/soak.sh [MINUTES] [RELOCD_BINARY]
#
# The binary defaults to the release build (built if missing). Prints one JSON summary line; exit 1 if a
# check fails. Uses examples/relocd_client.py.
set -euo pipefail
cd "$(dirname "$0")/.."
minutes="${1:-60}"
binary="${2:-}"
if [ -z "$binary" ]; then
    cargo build --release --quiet
    binary="${CARGO_TARGET_DIR:-target}/release/relocd"
fi
exec python3 - "$minutes" "$binary" <<'EOF'
import json, os, random, socket, subprocess, sys, tempfile, time

sys.path.insert(0, "examples")
from relocd_client import Control, Subscriber

minutes, binary = float(sys.argv[1]), sys.argv[2]
TEAM, PLAYER = 5, 2


def free_port():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def gamecontroller_packet(number, penalty):
    """RoboCupGameControlData v18 (118 bytes): our player's penalty (0 none, 7 request for pickup)."""
    def team(team_number, our_penalty):
        players = b"".join(bytes([our_penalty if i == PLAYER - 1 else 0, 0]) for i in range(20))
        return bytes([team_number, 0, 1, 1, 0, 0]) + (0).to_bytes(2, "little") + (1200).to_bytes(2, "little") + players
    header = b"RGme" + bytes([18, number, 7, 0, 0, 0, 3, 0, 1, TEAM]) + (300).to_bytes(2, "little", signed=True)
    header += (0).to_bytes(2, "little", signed=True)
    return header + team(TEAM, penalty) + team(12, 0)


def process_stats(pid):
    status = open(f"/proc/{pid}/status").read().splitlines()
    value = lambda key: int(next(line.split()[1] for line in status if line.startswith(key)))
    return {"rss_kib": value("VmRSS:"), "hwm_kib": value("VmHWM:"), "threads": value("Threads:"),
            "fds": len(os.listdir(f"/proc/{pid}/fd"))}


scratch = tempfile.mkdtemp(prefix="relocd-soak-")
control_port, publish_port, gc_port = free_port(), free_port(), free_port()
sensors = os.path.join(scratch, "sensors")
config = os.path.join(scratch, "relocd.toml")
with open(config, "w") as file:
    file.write(f'[publish]\ntargets = ["udp:127.0.0.1:{publish_port}"]\n[gamecontroller]\naddress = "127.0.0.1"\n')
subscriber = Subscriber(f"udp:127.0.0.1:{publish_port}")
daemon = subprocess.Popen(
    [binary, "run", "--config", config, "--source", "replay:tests/data/sample", "--team", str(TEAM),
     "--player", str(PLAYER), "--gc-port", str(gc_port), "--control", f"udp:127.0.0.1:{control_port}",
     "--sensors", f"unix:{sensors}"],
    stderr=open(os.path.join(scratch, "relocd.log"), "w"))
time.sleep(1.5)
control = Control(f"udp:127.0.0.1:{control_port}", timeout=5.0)
udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
unix = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
rng = random.Random(1)

awaited, answered, packet_number, triggers = set(), set(), 0, 0
warm, started, failures = None, time.monotonic(), []
try:
    while time.monotonic() - started < minutes * 60:
        triggers += 1
        if triggers % 2:
            awaited.add(control.relocalise(reason="soak"))
        else:
            for penalty in (7, 0):  # picked up, then back: a penalty return
                packet_number = (packet_number + 1) % 256
                udp.sendto(gamecontroller_packet(packet_number, penalty), ("127.0.0.1", gc_port))
                time.sleep(0.05)
        for _ in range(5):  # garbage on every input
            junk = bytes(rng.getrandbits(8) for _ in range(rng.randrange(1, 300)))
            udp.sendto(junk, ("127.0.0.1", control_port))
            udp.sendto(junk, ("127.0.0.1", gc_port))
            unix.sendto(junk, sensors)
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            try:
                message = subscriber.receive(timeout=max(0.01, deadline - time.monotonic()))
            except Exception:
                break
            answered.update(trigger["id"] for trigger in message.triggers)
        if warm is None and time.monotonic() - started > min(60.0, minutes * 30):
            warm = process_stats(daemon.pid)
    time.sleep(3.0)
    while True:
        try:
            answered.update(t["id"] for t in subscriber.receive(timeout=0.5).triggers)
        except Exception:
            break
    end = process_stats(daemon.pid)
    status = control.status()
finally:
    daemon.terminate()
    daemon.wait(timeout=10)

counted = sum(status["triggers"].values())
summary = {"minutes": minutes, "triggers_sent": triggers, "counted": counted, "bursts": status["bursts"],
           "coalesced": status["coalesced"], "rejected": status["rejected"], "warm": warm, "end": end,
           "unanswered_requests": sorted(awaited - answered)}
if awaited - answered:
    failures.append("requests without an answer")
if counted != status["bursts"] + status["coalesced"]:
    failures.append("triggers counted != bursts + coalesced")
if status["triggers"]["penalty_return"] < triggers // 2:
    failures.append("penalty returns missing")
if warm and end["hwm_kib"] > warm["hwm_kib"] * 1.05:
    failures.append("peak RSS grew by 5% or more after warm-up")
if warm and (end["fds"] != warm["fds"] or end["threads"] != warm["threads"]):
    failures.append("file descriptors or threads leaked")
summary["failures"] = failures
print(json.dumps(summary))
sys.exit(1 if failures else 0)
EOF
