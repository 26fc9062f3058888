"""``soilocp service ros2-in``: a ROS 2 robot's topics (rmw_zenoh) as the vehicle's sensor source.

It is the vehicle source of :mod:`soilocp.services.io.sensor_source` with another input: it opens a
second Zenoh session on the robot's router (rmw_zenohd), subscribes the map file's topics with
rmw_zenoh's key expressions (a ROS 2 node ``soilocp_ros2_in`` with ``MS`` liveliness tokens, so
the robot's ``ros2 topic info`` shows the reader), deserialises the CDR payloads with ``rosbags``
and aligns them with :class:`~soilocp.ingest.live.LiveAligner` (the bag import's conversion and
alignment).  The samples go out on ``soilocp/<vid>/sensors/raw`` like a synthetic or replayed
drive's, so the rest of the chain does not know the difference.

The Zenoh callback only enqueues (bounded; a full queue drops and counts); decoding and
alignment run on the source's own thread.
"""

from __future__ import annotations

import queue
import time
from collections import Counter
from typing import Iterator, Optional

from soilocp.services.io.sensor_source import VehicleService
from soilocp.services.ros2 import rmw_zenoh
from soilocp.services.stages.graph import PIPELINE_SERVICES
from soilocp.ingest.live import DEFAULT_LAG_S, LiveAligner
from soilocp.ingest.mapfile import TopicMap
from soilocp.ingest.rosbag_import import EXPECTED_TYPES

NODE_NAME = "soilocp_ros2_in"
#: wall s without any message: write the held ticks up to where every stream is fresh.  A flush
#: decides ticks that a message still in flight could have changed, so it waits well past any
#: pause of a live publisher (the estimates are already flagged stale after the OCP's timeout)
IDLE_FLUSH_S = 2.0
RAW_QUEUE = 20_000  # messages waiting for the decoder (~1 min of three topics at 100/50/20 Hz)
SILENT_REPORT_S = 5.0  # a mapped topic silent this long after subscribing: say which topics the robot has


class Ros2InService(VehicleService):
    name = "ros2-in"

    def __init__(self, cfg, log, *, tmap: TopicMap, ros2_connect: list[str], domain_id: int = 0,
                 wait_for: tuple[str, ...] = PIPELINE_SERVICES, wait_timeout_s: float = 20.0,
                 lag_s: float = DEFAULT_LAG_S, idle_flush_s: float = IDLE_FLUSH_S):
        if tmap.vehicle_id != cfg.vehicle_id:
            raise ValueError(f"the map's vehicle_id {tmap.vehicle_id!r} is not the service's {cfg.vehicle_id!r}")
        if not 0 <= domain_id <= 232:
            raise ValueError(f"ROS domain id {domain_id}: must be 0..232")
        self.aligner = LiveAligner(tmap, lag_s=lag_s, source="ros2 live (rmw_zenoh)")
        for topic in self.aligner.topics.values():
            rmw_zenoh.check_topic(topic)
        self.tmap, self.ros2_connect, self.domain_id = tmap, list(ros2_connect), int(domain_id)
        self.idle_flush_s = float(idle_flush_s)
        self._raw: queue.Queue = queue.Queue(maxsize=RAW_QUEUE)
        self.messages = Counter()  # per topic: received
        self.silent_topics: list[str] = []
        self.raw_dropped = 0
        self.ros_session = None
        self.node: Optional[rmw_zenoh.RosNode] = None
        describe = "ROS 2 topics " + ", ".join(self.aligner.topics.values()) + f" via {', '.join(self.ros2_connect)}"
        super().__init__(cfg, log, source=self._samples(), speed=0.0, wait_for=wait_for,
                         wait_timeout_s=wait_timeout_s, describe=describe)

    # --- the ROS 2 side ----------------------------------------------------------------------------
    def _on_message(self, sample) -> None:
        try:
            att = sample.attachment
            self._raw.put_nowait((str(sample.key_expr), sample.payload.to_bytes(),
                                  None if att is None else att.to_bytes(), time.time_ns()))
        except queue.Full:
            self.raw_dropped += 1

    def _open(self) -> bool:
        self.ros_session = rmw_zenoh.open_ros_session(self.ros2_connect, self.stop_event, self.log)
        if self.ros_session is None:
            return False
        self.node = rmw_zenoh.RosNode(self.ros_session, self.domain_id, NODE_NAME)
        for role, topic in self.aligner.topics.items():
            self.node.subscription(topic, EXPECTED_TYPES[role], self._on_message)
        if not self.aligner.prov.identifiable:
            self.log.warning("not_identifiable", reasons=self.aligner.prov.reasons)
        self.log.info("ros2_subscribed", domain_id=self.domain_id, topics=self.aligner.topics)
        return True

    def _decode(self, key: str, payload: bytes, att: Optional[bytes], receive_ns: int) -> None:
        """One data sample of the robot: checked against rmw_zenoh's key and attachment, decoded
        with rosbags, given to the aligner; anything that does not fit is counted with its reason."""
        al = self.aligner
        try:
            _dom, topic, dds, hash_ = rmw_zenoh.split_topic_key(key)
        except ValueError as exc:
            al.issues.add(key, "key", str(exc), receive_ns)
            return
        self.messages[topic] += 1
        role = al.role_of(topic)
        ros_type = rmw_zenoh.ros_type_name(dds)
        if role is None:  # the selector is per topic: only a foreign publisher's odd key lands here
            al.issues.add(topic, "key", "topic not in the map", receive_ns)
            return
        if ros_type not in EXPECTED_TYPES[role]:
            al.issues.add(topic, "type", f"{dds} cannot feed {role}: needs " + " or ".join(EXPECTED_TYPES[role]),
                          receive_ns)
            return
        if hash_ not in (rmw_zenoh.type_hash(ros_type), rmw_zenoh.NO_TYPE_HASH):
            al.issues.add(topic, "type_hash", f"{hash_} is not {ros_type}'s {rmw_zenoh.type_hash(ros_type)} "
                          "(the robot's message definition differs)", receive_ns)
            return
        if att is None:  # rmw_zenoh subscribers drop these too ("Unable to obtain attachment")
            al.issues.add(topic, "attachment", "missing (not an rmw_zenoh publisher)", receive_ns)
            return
        try:
            rmw_zenoh.parse_attachment(att)
        except ValueError as exc:
            al.issues.add(topic, "attachment", str(exc), receive_ns)
            return
        try:
            msg = rmw_zenoh.typestore().deserialize_cdr(payload, ros_type)
        except Exception as exc:  # rosbags raises assorted errors on bytes that are not this type's CDR
            al.issues.add(topic, "payload", f"CDR does not decode as {ros_type}: {type(exc).__name__}", receive_ns)
            return
        al.add(role, msg, ros_type, receive_ns)

    def _samples(self) -> Iterator[tuple[bytes, Optional[float]]]:
        """The sensor samples, as the aligner releases them (runs on the source's thread)."""
        if not self._open():
            return
        last_msg = time.monotonic()
        next_report = last_msg + SILENT_REPORT_S
        flushed = True
        while not self.stop_event.is_set():
            try:
                item = self._raw.get(timeout=0.05)
            except queue.Empty:
                item = None
            n = 0
            while item is not None:
                self._decode(*item)
                n += 1
                try:
                    item = self._raw.get_nowait() if n < 500 else None
                except queue.Empty:
                    item = None
            now = time.monotonic()
            if now >= next_report:
                next_report = now + 6 * SILENT_REPORT_S
                self._report_silent_topics()
            if n:
                last_msg, flushed = now, False
                out = self.aligner.ready()
            elif not flushed and now - last_msg > self.idle_flush_s:
                out, flushed = self.aligner.flush(), True
            else:
                out = []
            for s in out:
                yield s.model_dump_json().encode(), s.stamp

    def _report_silent_topics(self) -> None:
        """A mapped topic that never delivered: log the robot's published topics (a wrong name,
        domain or type is the usual cause), and keep the list in the health detail."""
        silent = [t for t in self.aligner.topics.values() if not self.messages.get(t)]
        if not silent:
            return
        try:
            graph = rmw_zenoh.graph_publishers(self.ros_session, self.domain_id)
        except Exception as exc:  # a failed graph query must not stop the reader
            graph = {"<graph query failed>": {f"{type(exc).__name__}: {exc}"[:200]}}
        self.silent_topics = silent
        self.log.warning("ros2_topics_silent", silent=silent, domain_id=self.domain_id,
                         published_in_graph={t: sorted(v) for t, v in sorted(graph.items())})

    def health_extra(self, vehicle_id: str) -> dict:
        al = self.aligner
        detail = {**self.counters[vehicle_id].detail, "samples": al.samples, "raw_dropped": self.raw_dropped,
                  "silent_topics": ",".join(t for t in self.silent_topics if not self.messages.get(t)),
                  **{f"messages {t}": n for t, n in self.messages.items()},
                  **{f"dropped {k}": n for k, n in al.dropped().items()},
                  **{f"skipped {k}": n for k, n in al.skipped.items()}}
        return {"detail": detail, "dropped": self.counters[vehicle_id].dropped + self.raw_dropped}

    def close(self) -> None:
        rmw_zenoh.close_ros(self.node, self.ros_session)
        super().close()
