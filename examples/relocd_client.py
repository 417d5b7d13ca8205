#!/usr/bin/env python3
"""A relocd client in one file: receive relocd's hypotheses and ask it to relocalise.

Standard library only (Python 3.8+); MessagePack messages need the optional `msgpack` package.
Copy this file into your code base, or run it to watch what relocd publishes:

    python3 relocd_client.py                              # print every message on udp:127.0.0.1:5454
    python3 relocd_client.py --request "lost"             # ask for a relocalisation, print its answer
    python3 relocd_client.py --listen unix:/tmp/loc --control udp:127.0.0.1:5455 --request

As a library:

    from relocd_client import Control, Subscriber
    hypotheses = Subscriber("udp:127.0.0.1:5454")
    trigger = Control("unix:/tmp/relocd-control").relocalise(reason="particle filter diverged")
    message = hypotheses.receive_answer(trigger, timeout=5.0)
    best = message.best()                  # Hypothesis(x, y, theta, weight, sigma) or None

The message format is docs/protocol.md (schema 1).
"""

import argparse
import json
import math
import os
import socket
import stat
import sys
import tempfile
import time
from dataclasses import dataclass
from typing import List, Optional, Tuple

SCHEMA_VERSION = 1
MAX_DATAGRAM = 65536

try:
    import msgpack  # optional: only for `encoding = "msgpack"`
except ImportError:
    msgpack = None


class RelocdError(Exception):
    """A datagram that is not a relocd message, a refused request, or no answer in time."""


@dataclass
class Hypothesis:
    """One weighted full-field robot pose: metres, radians, sigma = (sx, sy, stheta); `lines` says what
    the field lines made of it ("refined", "partial", "unrefined", "contradicted"; None when off)."""

    x: float
    y: float
    theta: float
    weight: float
    sigma: Tuple[float, float, float]
    lines: Optional[str] = None


@dataclass
class Message:
    """A hypotheses message; `raw` keeps every key, including ones this client does not know."""

    seq: int
    triggers: List[dict]
    hypotheses: List[Hypothesis]
    failure: Optional[str]
    raw: dict

    def best(self) -> Optional[Hypothesis]:
        """The heaviest hypothesis, or None when relocalisation failed."""
        return self.hypotheses[0] if self.hypotheses else None

    def answers(self, trigger: int) -> bool:
        """Whether this message answers trigger id `trigger`."""
        return any(t.get("id") == trigger for t in self.triggers)


def decode(data: bytes) -> Message:
    """Decodes one datagram, JSON or MessagePack, and checks it as relocd's reference decoder does."""
    try:
        if data[:1] == b"{":
            raw = json.loads(data.decode("utf-8"))
        elif msgpack is not None:
            raw = msgpack.unpackb(data, raw=False)
        else:
            raise RelocdError("a MessagePack message: install the msgpack package, or publish json")
    except (ValueError, UnicodeDecodeError) as error:
        raise RelocdError(f"not a relocd message: {error}") from None
    if not isinstance(raw, dict) or raw.get("schema") != SCHEMA_VERSION:
        schema = raw.get("schema") if isinstance(raw, dict) else None
        raise RelocdError(f"relocd message schema {schema}, this client understands {SCHEMA_VERSION}")
    try:
        hypotheses = [
            Hypothesis(float(h["x"]), float(h["y"]), float(h["theta"]), float(h["weight"]),
                       tuple(float(s) for s in h["sigma"]), (h.get("lines") or {}).get("check"))
            for h in raw["hypotheses"]
        ]
        message = Message(int(raw["seq"]), list(raw["triggers"]), hypotheses, raw.get("failure"), raw)
    except (KeyError, TypeError, ValueError) as error:
        raise RelocdError(f"not a relocd message: {error!r}") from None
    if not message.triggers or bool(hypotheses) == (message.failure is not None):
        raise RelocdError("not a relocd message: it needs triggers and either hypotheses or a failure")
    for h in hypotheses:
        numbers = (h.x, h.y, h.theta, h.weight) + h.sigma
        if len(h.sigma) != 3 or not all(map(math.isfinite, numbers)) or not 0 <= h.weight <= 1 \
                or min(h.sigma) < 0:
            raise RelocdError("not a relocd message: a hypothesis is not finite, weighted in [0, 1] with sigma >= 0")
    return message


def _socket_for(address: str) -> Tuple[socket.socket, object]:
    """An unbound datagram socket for `udp:IP:PORT` or `unix:PATH`, and the address to use with it."""
    kind, _, rest = address.partition(":")
    if kind == "udp":
        host, _, port = rest.rpartition(":")
        host = host.strip("[]")
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        return socket.socket(family, socket.SOCK_DGRAM), (host, int(port))
    if kind == "unix" and rest:
        return socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM), rest
    raise ValueError(f"{address!r}: expected udp:IP:PORT or unix:PATH")


def _remove_stale_socket(path: str) -> None:
    """Removes a socket file left behind by a process that died; refuses a live one or a file."""
    if not stat.S_ISSOCK(os.stat(path).st_mode):
        raise OSError(f"{path} exists and is not a socket")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    try:
        probe.connect(path)
        raise OSError(f"{path} is in use by another process")
    except ConnectionRefusedError:
        os.unlink(path)
    finally:
        probe.close()


class Subscriber:
    """Receives the messages relocd publishes to `address` (one of its `publish.targets`)."""

    def __init__(self, address: str):
        self.socket, self.address = _socket_for(address)
        if isinstance(self.address, str) and os.path.exists(self.address):
            _remove_stale_socket(self.address)
        self.socket.bind(self.address)

    def receive(self, timeout: Optional[float] = None) -> Message:
        """The next message; raises RelocdError for a datagram that is not one, TimeoutError after
        `timeout` seconds (None: wait for ever, 0: do not wait)."""
        self.socket.settimeout(timeout)
        try:
            data = self.socket.recv(MAX_DATAGRAM)
        except (socket.timeout, BlockingIOError):
            raise TimeoutError("no relocd message") from None
        return decode(data)

    def receive_answer(self, trigger: int, timeout: float) -> Message:
        """The message answering trigger `trigger`, skipping others, within `timeout` seconds."""
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"no answer to trigger {trigger} within {timeout} s")
            try:
                message = self.receive(left)
            except RelocdError:
                continue
            if message.answers(trigger):
                return message

    def close(self) -> None:
        self.socket.close()
        if isinstance(self.address, str) and os.path.exists(self.address):
            os.unlink(self.address)


class Control:
    """Asks relocd (its `control` address) to relocalise or for its status."""

    def __init__(self, address: str, timeout: float = 2.0):
        self.socket, self.daemon = _socket_for(address)
        self.own_path = None
        if self.socket.family == socket.AF_UNIX:
            # relocd answers to the sender's path, so bind one of our own.
            self.own_path = os.path.join(tempfile.gettempdir(), f"relocd-client-{os.getpid()}-{id(self)}")
            self.socket.bind(self.own_path)
        self.timeout = timeout

    def _ask(self, request: dict, key: str) -> dict:
        """Sends `request`; returns the `key` member of its answer. Answers that came after an earlier
        request timed out are discarded first, so they cannot pass for this one's."""
        self.socket.setblocking(False)
        try:
            while True:
                self.socket.recv(MAX_DATAGRAM)
        except BlockingIOError:
            pass
        self.socket.settimeout(self.timeout)
        self.socket.sendto(json.dumps(request).encode(), self.daemon)
        try:
            answer = json.loads(self.socket.recv(MAX_DATAGRAM))
        except socket.timeout:
            raise TimeoutError("relocd did not answer the control request") from None
        except ValueError as error:
            raise RelocdError(f"unexpected answer from relocd: {error}") from None
        if not isinstance(answer, dict):
            raise RelocdError(f"unexpected answer from relocd: {answer!r}")
        if "error" in answer:
            raise RelocdError(f"relocd refused the request: {answer['error']}")
        if key not in answer:
            raise RelocdError(f"unexpected answer from relocd: {answer!r}")
        return answer[key]

    def relocalise(self, reason: Optional[str] = None, head_yaw: Optional[float] = None) -> int:
        """Asks for a relocalisation; returns the trigger id the published message will list (the
        request's own, or the waiting one it joined when relocd had too many waiting)."""
        request = {}
        if reason is not None:
            request["reason"] = reason
        if head_yaw is not None:
            request["head_yaw"] = head_yaw
        accepted = self._ask({"relocalise": request}, "accepted")
        if not isinstance(accepted, dict) or not isinstance(accepted.get("trigger"), int):
            raise RelocdError(f"unexpected answer from relocd: {accepted!r}")
        joined = accepted.get("coalesced_into")
        return joined if isinstance(joined, int) else accepted["trigger"]

    def relocalise_with(self, reason: Optional[str] = None, head_yaw: Optional[float] = None,
                        prior: Optional[dict] = None, own_half: Optional[bool] = None,
                        ball: Optional[dict] = None) -> dict:
        """Asks for a relocalisation with context that tells the symmetric twins apart (docs/protocol.md,
        "Relocalise context"): `prior` {"pose": {...}}, `own_half`, `ball` {"own": {...}, "team": {...}}.
        Returns {"trigger": id the published message will list, "context_errors": [...]}: context relocd
        could not use is left out and named there; the relocalisation runs anyway."""
        request = {}
        for key, value in (("reason", reason), ("head_yaw", head_yaw), ("prior", prior),
                           ("own_half", own_half), ("ball", ball)):
            if value is not None:
                request[key] = value
        accepted = self._ask({"relocalise": request}, "accepted")
        if not isinstance(accepted, dict) or not isinstance(accepted.get("trigger"), int):
            raise RelocdError(f"unexpected answer from relocd: {accepted!r}")
        joined = accepted.get("coalesced_into")
        return {"trigger": joined if isinstance(joined, int) else accepted["trigger"],
                "context_errors": list(accepted.get("context_errors", []))}

    def belief(self, pose: dict) -> None:
        """Sends the team's current pose estimate {"x", "y", "theta", "sigma": {"x", "y", "theta"}[, "age_s"]}
        (the belief stream, 1-10 Hz): the last one from before a fall or pick-up becomes that
        relocalisation's prior. relocd does not answer; a refused belief is logged and counted there."""
        self.socket.sendto(json.dumps({"belief": pose}).encode(), self.daemon)

    def status(self) -> dict:
        """relocd's counters, game state and last latencies."""
        return self._ask({"status": {}}, "status")

    def close(self) -> None:
        self.socket.close()
        if self.own_path and os.path.exists(self.own_path):
            os.unlink(self.own_path)


def describe(message: Message) -> str:
    """One line for a message: its triggers and its best hypothesis or failure."""
    triggers = ", ".join(f"{t.get('id')} {t.get('kind')}" for t in message.triggers)
    best = message.best()
    if best is None:
        return f"seq {message.seq} triggers [{triggers}]: failed: {message.failure}"
    return (f"seq {message.seq} triggers [{triggers}]: best x={best.x:.3f} m y={best.y:.3f} m "
            f"theta={best.theta:.3f} rad weight={best.weight:.3f} ({len(message.hypotheses)} hypotheses)")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--listen", default="udp:127.0.0.1:5454", help="where relocd publishes")
    parser.add_argument("--control", default="unix:/tmp/relocd-control", help="relocd's control socket")
    parser.add_argument("--request", nargs="?", const="", metavar="REASON",
                        help="ask for a relocalisation and print only its answer")
    parser.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for an answer")
    args = parser.parse_args()

    subscriber = Subscriber(args.listen)
    try:
        if args.request is None:
            while True:
                try:
                    print(describe(subscriber.receive()), flush=True)
                except RelocdError as error:
                    print(f"skipped: {error}", file=sys.stderr)
        control = Control(args.control)
        try:
            trigger = control.relocalise(reason=args.request or None)
        finally:
            control.close()
        print(f"accepted as trigger {trigger}", file=sys.stderr)
        message = subscriber.receive_answer(trigger, args.timeout)
        print(describe(message), flush=True)
        return 0 if message.best() is not None else 1
    except (RelocdError, TimeoutError, OSError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 0
    finally:
        subscriber.close()


if __name__ == "__main__":
    sys.exit(main())
