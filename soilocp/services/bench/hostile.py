"""Hostile raw payloads: the seeded generator of the parser's fuzz test and a flooding publisher.

:func:`mutate` draws one hostile payload of a kind: oversized, truncated, byte-flipped or invalid
UTF-8, a field replaced by a hostile literal (NaN, 1e400, a string, 4000 digits...), a non-finite
vector element, deep nesting under the byte limit, huge or odd seq / stamp, missing / extra /
wrong-length fields, not an object, random bytes, an array of numbers up to the limit, duplicate
keys, or a valid sample (possibly of another vehicle).  The same seed gives the same payloads.

:func:`flood_payloads` adds what only a live stream can be attacked with: the vehicle's own
samples replayed (old and duplicate seq, in order, as a recorded stream would be), samples with
stamps far in the future but an old seq, and valid samples naming another vehicle.  Every one of
them must be refused by the gateway while the vehicle's own stream (higher seqs, later stamps)
goes through; a forged sample with a *higher* seq and a later stamp is the vehicle's, as far as
any check without authentication can tell (docs/services.md, "A hostile publisher").

``python -m soilocp.services.bench.hostile --connect EP --vehicle-id V --rate HZ --duration S`` floods
``soilocp/V/sensors/raw`` from its own Zenoh session, bounded in count (rate x duration) and time,
and prints one JSON line: what it sent, by kind.
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import time
from typing import Optional

from soilocp.validation import MAX_PAYLOAD_BYTES

_HOSTILE_VALUES = ("NaN", "Infinity", "-Infinity", "1e400", "-1e400", "1e-400", "null", "true", '"x"', "[]", "{}",
                   "[1,2,3]", '"NaN"', "9" * 300, "-" + "9" * 4000, "0." + "0" * 3000 + "1", "1" + "0" * 4300,
                   "1e99999999999", "0x10", "+1", ".5", "01", "\"\\ud800\"", "2e308")


def good_sample(seq: int, vehicle_id: str = "rover1", stamp: Optional[float] = None) -> dict:
    """A valid sample as a dict (the base every mutation starts from)."""
    return {"vehicle_id": vehicle_id, "seq": seq, "stamp": 0.01 * seq if stamp is None else stamp,
            "specific_force": [0.1, -0.2, 9.81], "roll": 0.01, "pitch": -0.02, "yaw_rate": 0.003,
            "wheel_speed": [3.0, 3.1, 2.9, 3.0], "wheel_torque": [1.5, 1.4, 1.6, 1.5], "ground_speed": 0.45}


def mutate(rng: random.Random, seq: int, vehicle_id: str = "rover1") -> bytes:
    """One hostile payload, of a kind drawn by ``rng`` (module doc)."""
    base = good_sample(seq)
    base["vehicle_id"] = rng.choice((vehicle_id,) * 3 + ("rover2", "x" * 64, "", "a/b", "x" * 65))
    text = json.dumps(base, indent=rng.choice((None, None, 2)))
    kind = rng.randrange(14)
    if kind == 0:  # oversized: whitespace, or a valid-looking array, a little or far past the limit
        size = rng.choice((MAX_PAYLOAD_BYTES + 1, MAX_PAYLOAD_BYTES + rng.randrange(1, 5000),
                           rng.randrange(10_000, 600_000)))
        filler = rng.choice((b" ", b"1,", b"[", b"9"))
        return (text[:-1].encode() + filler * (size // len(filler)) + b"}")[:size + rng.randrange(2)]
    if kind == 1:  # truncated
        return text.encode()[:rng.randrange(len(text))]
    if kind == 2:  # bytes flipped or inserted, invalid UTF-8 included
        b = bytearray(text.encode())
        for _ in range(rng.randrange(1, 6)):
            i = rng.randrange(len(b))
            if rng.random() < 0.5:
                b[i] = rng.randrange(256)
            else:
                b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 4)))
        return bytes(b)
    if kind in (3, 4):  # one field's value replaced by a hostile literal
        field = rng.choice(list(base))
        value = rng.choice(_HOSTILE_VALUES)
        out = text.replace(json.dumps(base[field]), value, 1)
        if out == text:
            out = text.replace(f'"{field}": ', f'"{field}": {value}, "_x": ', 1)
        return out.encode()
    if kind == 5:  # an element of a vector replaced
        field = rng.choice(("specific_force", "wheel_speed", "wheel_torque"))
        v = list(base[field])
        v[rng.randrange(len(v))] = rng.choice((float("nan"), float("inf"), -float("inf"), 1e308, -1e308, 5e-324))
        base[field] = v
        return json.dumps(base).encode()  # json.dumps writes NaN / Infinity
    if kind == 6:  # deep nesting under the limit
        opener, closer = rng.choice((("[", "]"), ('{"a":', "}"), ('{"seq":', "}")))
        depth = min(rng.randrange(10, MAX_PAYLOAD_BYTES // 2), MAX_PAYLOAD_BYTES // (len(opener) + len(closer)))
        return (opener * depth + rng.choice(("1", "NaN", "")) + closer * depth).encode()
    if kind == 7:  # huge or odd numbers for seq / stamp
        field = rng.choice(("seq", "stamp"))
        base[field] = rng.choice((-1, 2**63, 2**64 + 1, 10**300, -10**300, 1e308, True, 0.5, "1", None))
        return json.dumps(base).encode()
    if kind == 8:  # a field missing, an extra one, a vector of the wrong length
        what = rng.randrange(3)
        if what == 0:
            base.pop(rng.choice(list(base)))
        elif what == 1:
            base[rng.choice(("extra", "$id", "__proto__", "vehicle_id "))] = 1
        else:
            field = rng.choice(("specific_force", "wheel_speed", "wheel_torque"))
            base[field] = base[field] * rng.choice((0, 2)) + [0.0] * rng.randrange(2)
        return json.dumps(base).encode()
    if kind == 9:  # not an object at all
        return rng.choice((b"", b"null", b"[]", b"1", b'"x"', b"true", b"\xff\xfe", b"\x00" * 64, b"{}", b"{" * 3,
                           json.dumps([base]).encode()))
    if kind == 10:  # random bytes
        return bytes(rng.randrange(256) for _ in range(rng.randrange(0, 300)))
    if kind == 11:  # an array of numbers up to the limit (the most parsing a payload under the limit buys)
        n = rng.randrange(100, MAX_PAYLOAD_BYTES // 2)
        return ("[" + ",".join("1" for _ in range(n)) + "]").encode()[:MAX_PAYLOAD_BYTES]
    if kind == 12:  # duplicate keys, the last one hostile
        return (text[:-1] + ', "seq": ' + rng.choice(_HOSTILE_VALUES) + "}").encode()
    return text.encode()  # valid (the vehicle may be another one, or an empty id)


#: The kinds of :func:`flood_payloads`, with their share of the flood.
FLOOD_KINDS = {"mutated": 0.55, "replayed": 0.2, "future_stamp": 0.1, "wrong_vehicle": 0.1, "oversized": 0.05}


def flood_payloads(vehicle_id: str, n: int, seed: int = 0, below_seq: int = 1_000_000
                   ) -> list[tuple[str, bytes]]:
    """``n`` hostile ``(kind, payload)`` for ``vehicle_id``'s raw key (module doc).  The vehicle's own
    stream must use seqs from ``below_seq`` up: every replayed or future-stamped sample here has a
    lower seq, so the gateway must refuse it (old_seq / duplicate_seq / stamp_backwards)."""
    rng = random.Random(seed)
    kinds = list(FLOOD_KINDS)
    weights = [FLOOD_KINDS[k] for k in kinds]
    out: list[tuple[str, bytes]] = []
    replay_seq = 0
    while len(out) < n:
        kind = rng.choices(kinds, weights)[0]
        if kind == "mutated":
            p = mutate(rng, rng.randrange(below_seq), vehicle_id)
        elif kind == "replayed":  # a recorded stream, replayed in order (50 and more in a row)
            for _ in range(rng.randrange(1, 80)):
                replay_seq = (replay_seq + 1) % below_seq
                out.append(("replayed", json.dumps(good_sample(replay_seq, vehicle_id)).encode()))
            continue
        elif kind == "future_stamp":
            p = json.dumps(good_sample(rng.randrange(below_seq), vehicle_id, stamp=1e9 + rng.random() * 1e6)).encode()
        elif kind == "wrong_vehicle":
            p = json.dumps(good_sample(below_seq + rng.randrange(10**6), "intruder")).encode()
        else:
            p = b'{"vehicle_id": "' + vehicle_id.encode() + b'", "pad": "' + b"x" * rng.randrange(5000, 200_000) + b'"}'
        out.append((kind, p))
    return out[:n]


def flood(session, key: str, payloads: list[tuple[str, bytes]], rate: float, duration: float) -> dict:
    """Put ``payloads`` (cycled) on ``key`` at ``rate`` per second for at most ``duration`` s, in bursts
    of one millisecond's share; returns what was sent, by kind, and the rate achieved."""
    import zenoh

    pub = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.DROP)
    sent: dict[str, int] = {}
    n_max = int(rate * duration)
    burst = max(1, int(round(rate / 1000.0)))
    t0 = time.perf_counter()
    wall0 = time.time()
    i = 0
    try:
        while i < n_max:
            due = t0 + i / rate
            now = time.perf_counter()
            if now - t0 > duration + 1.0:
                break  # bounded in time too: a slow machine sends fewer, never longer
            if due > now:
                time.sleep(due - now)
            for _ in range(min(burst, n_max - i)):
                kind, p = payloads[i % len(payloads)]
                pub.put(p)
                sent[kind] = sent.get(kind, 0) + 1
                i += 1
    finally:
        pub.undeclare()
    elapsed = time.perf_counter() - t0
    return {"sent": i, "by_kind": sent, "seconds": elapsed, "rate": i / max(elapsed, 1e-9), "start_wall": wall0,
            "end_wall": wall0 + elapsed}


def main(argv: Optional[list[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m soilocp.services.bench.hostile", description=__doc__.split("\n\n")[0])
    ap.add_argument("--connect", required=True)
    ap.add_argument("--vehicle-id", required=True)
    ap.add_argument("--rate", type=float, default=10_000.0, help="payloads per second")
    ap.add_argument("--duration", type=float, default=3.0, help="seconds (and at most one more)")
    ap.add_argument("--delay", type=float, default=0.0, help="seconds to wait after connecting")
    ap.add_argument("--pool", type=int, default=5000, help="distinct payloads, cycled")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--below-seq", type=int, default=1_000_000)
    a = ap.parse_args(argv)
    import zenoh

    from soilocp.schemas import keys
    from soilocp.services.runtime.settings import zenoh_config

    payloads = flood_payloads(a.vehicle_id, a.pool, a.seed, a.below_seq)
    with zenoh.open(zenoh_config("client", [a.connect], [], connect_timeout_ms=10_000)) as session:
        time.sleep(a.delay)
        report = flood(session, keys.raw(a.vehicle_id), payloads, a.rate, a.duration)
    print(json.dumps(report), flush=True)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
