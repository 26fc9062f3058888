"""A ROS 2 "robot" made with zenoh-ros2-sdk (an rmw_zenoh implementation from PyPI that this
project did not write), in its own process, for tests/test_ros2_zenoh.py.

It waits until the graph (liveliness tokens, read with the SDK's own discovery) shows soilocp's
subscriptions on the robot's topics and its publishers, then publishes every message of a bag on
its topic (paced by the bag's log time / ``--speed``), subscribes soilocp's topics with the SDK's
subscribers (which decode the CDR with rosbags), also reads the raw samples to check
rmw_zenoh's attachment, and prints one JSON document on stdout.

    python tests/ros2_robot.py BAG MSG_DIR ROUTER_PORT VEHICLE_ID EXPECTED --speed 4
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import struct
import sys
import time


def _num(x):
    return None if isinstance(x, float) and math.isnan(x) else x


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("bag")
    ap.add_argument("msg_dir")
    ap.add_argument("port", type=int)
    ap.add_argument("vehicle_id")
    ap.add_argument("expected", type=int, help="estimates to wait for")
    ap.add_argument("--speed", type=float, default=4.0)
    ap.add_argument("--timeout", type=float, default=60.0)
    a = ap.parse_args()

    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore
    from zenoh_ros2_sdk import (ROS2Publisher, ROS2Subscriber, ZenohSession, get_registry, get_topic_info,
                                get_topic_names_and_types)

    get_registry(a.msg_dir)  # message definitions from this directory, not from a git clone
    sdk = ZenohSession.get_instance("127.0.0.1", a.port)
    est_topic = f"/soilocp/{a.vehicle_id}/estimate"
    out = {"estimates": [], "diagnostics": [], "attachments": [], "errors": []}

    def on_estimate(m):
        out["estimates"].append({
            "seq": int(m.seq), "stamp": m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, "vehicle_id": m.vehicle_id,
            "frame_id": m.header.frame_id, "status": m.status, "reason": m.reason,
            "soil_strength": _num(m.soil_strength), "soil_strength_std": _num(m.soil_strength_std),
            "soil_class": m.soil_class or None, "soil_class_confidence": _num(m.soil_class_confidence),
            "mu_T": _num(m.mu_t), "S_T": _num(m.s_t), "S_E": _num(m.s_e), "te_at_S_E": _num(m.te_at_s_e),
            "mu": [float(x) for x in m.mu], "mu_determined": [bool(x) for x in m.mu_determined],
            "slip": [float(x) for x in m.slip]})

    def on_diag(m):
        out["diagnostics"].append([{"level": int(s.level), "name": s.name, "message": s.message,
                                    "values": {kv.key: kv.value for kv in s.values}} for s in m.status])

    def on_raw(sample):
        att = sample.attachment
        if att is None:
            out["errors"].append(f"no attachment on {sample.key_expr}")
            return
        b = att.to_bytes()
        # design.md: int64 sequence number, int64 source timestamp (ns), 1-byte GID length, GID
        seq, ts = struct.unpack_from("<qq", b)
        out["attachments"].append({"key": str(sample.key_expr), "len": len(b), "seq": seq, "ts": ts,
                                   "gid_len": b[16], "gid": b[17:].hex(),
                                   "encoding": str(sample.encoding)})

    subs = [ROS2Subscriber(est_topic, "soilocp_msgs/msg/SoilEstimate", on_estimate, router_port=a.port, domain_id=0),
            ROS2Subscriber("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", on_diag, router_port=a.port,
                           domain_id=0)]
    raw = sdk.session.declare_subscriber(f"0/soilocp/{a.vehicle_id}/estimate/*/*", on_raw)

    ts = get_typestore(Stores.ROS2_JAZZY)
    with AnyReader([__import__("pathlib").Path(a.bag)], default_typestore=ts) as r:
        conns = {c.topic: c for c in r.connections}
        pubs = {t: ROS2Publisher(t, c.msgtype, router_port=a.port, domain_id=0, node_name="robot_driver")
                for t, c in conns.items()}
        # soilocp's reader and writer are in the graph before the first message goes out
        deadline = time.monotonic() + a.timeout
        while True:
            infos = {t: get_topic_info(t, domain_id=0, router_port=a.port, verbose=True) for t in conns}
            est = get_topic_info(est_topic, domain_id=0, router_port=a.port, verbose=True)
            if all(i is not None and i.subscriber_count >= 1 for i in infos.values()) and est and est.publisher_count:
                break
            if time.monotonic() > deadline:
                print(json.dumps({"error": "soilocp's endpoints never appeared in the graph",
                                  "graph": get_topic_names_and_types(domain_id=0, router_port=a.port)}))
                return 1
            time.sleep(0.2)
        out["graph"] = get_topic_names_and_types(domain_id=0, router_port=a.port)
        out["subscribers"] = {t: [(s.node_name, s.topic_type) for s in i.subscribers] for t, i in infos.items()}
        out["estimate_publishers"] = [(p.node_name, p.topic_type, p.type_hash, p.qos)
                                      for p in est.publishers]
        t0 = s0 = None
        n = 0
        for conn, log_time, data in r.messages():
            msg = r.deserialize(data, conn.msgtype)
            if t0 is None:
                t0, s0 = time.monotonic(), log_time
            delay = t0 + (log_time - s0) / 1e9 / a.speed - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            pubs[conn.topic].publish(**{f.name: getattr(msg, f.name) for f in dataclasses.fields(msg)})
            n += 1
        out["published"] = n
    deadline = time.monotonic() + a.timeout
    while (len(out["estimates"]) < a.expected or len(out["diagnostics"]) < 2) and time.monotonic() < deadline:
        time.sleep(0.1)
    time.sleep(0.5)  # nothing more may arrive
    raw.undeclare()
    print(json.dumps(out))
    for s in subs:
        s.close()
    for p in pubs.values():
        p.close()
    sdk.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
