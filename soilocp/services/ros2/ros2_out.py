"""``soilocp service ros2-out``: the vehicle's estimates and health as ROS 2 topics (rmw_zenoh).

Whatever the source (synthetic, replay, ROS 2), it subscribes ``soilocp/<vid>/ocp`` and the
services' health (``soilocp/<vid>/status/*``) and publishes, on a second Zenoh session opened on
the robot's router, as the ROS 2 node ``soilocp`` (liveliness tokens ``NN`` and ``MP``):

* ``/soilocp/<vid>/estimate`` (``soilocp_msgs/msg/SoilEstimate``): every OCP record;
* ``/diagnostics`` (``diagnostic_msgs/msg/DiagnosticArray``), once a second: one status for the
  estimate and one per service, levels OK / WARN / ERROR / STALE (see soilocp.services.ros2.messages).
"""

from __future__ import annotations

import time
from typing import Optional

from soilocp.schemas import keys
from soilocp.schemas.messages import ServiceHealth
from soilocp.schemas.pipeline import OcpEstimate
from soilocp.services.ros2 import messages, rmw_zenoh
from soilocp.services.runtime.service import Service
from soilocp.services.runtime.worker import WorkItem

NODE_NAME = "soilocp"
DIAGNOSTICS_TOPIC = "/diagnostics"
DIAGNOSTICS_PERIOD_S = 1.0  # diagnostic_updater's default rate
HEALTH_STALE_AFTER_S = 3.0  # a service whose reports stopped this long ago is STALE


def estimate_topic(vehicle_id: str) -> str:
    return f"/soilocp/{vehicle_id}/estimate"


class Ros2OutService(Service):
    name = "ros2-out"

    def __init__(self, cfg, log, *, ros2_connect: list[str], domain_id: int = 0, frame_id: str = "base_link"):
        super().__init__(cfg, log)
        if not 0 <= domain_id <= 232:
            raise ValueError(f"ROS domain id {domain_id}: must be 0..232")
        for vid in cfg.vehicle_ids:
            rmw_zenoh.check_topic(estimate_topic(vid))
        self.ros2_connect, self.domain_id, self.frame_id = list(ros2_connect), int(domain_id), frame_id
        self.ros_session = None
        self.node: Optional[rmw_zenoh.RosNode] = None
        self.estimate_pubs: dict[str, rmw_zenoh.RosPublisher] = {}
        self.diag_pub: Optional[rmw_zenoh.RosPublisher] = None
        self.latest: dict[str, tuple[OcpEstimate, float]] = {}
        self.healths: dict[tuple[str, str], tuple[ServiceHealth, float]] = {}
        self._next_diag = 0.0

    def declare(self, session, vehicle_id: str) -> None:
        if self.node is None:
            self.ros_session = rmw_zenoh.open_ros_session(self.ros2_connect, self.stop_event, self.log)
            if self.ros_session is None:
                return
            self.node = rmw_zenoh.RosNode(self.ros_session, self.domain_id, NODE_NAME)
            self.diag_pub = self.node.publisher(DIAGNOSTICS_TOPIC, rmw_zenoh.DIAGNOSTICS_TYPE)
        self.estimate_pubs[vehicle_id] = self.node.publisher(estimate_topic(vehicle_id), rmw_zenoh.ESTIMATE_TYPE)
        self.subscribe(session, keys.ocp(vehicle_id), vehicle_id, "ocp")
        self.subscribe(session, keys.vehicle_status_all(vehicle_id), vehicle_id, "status")
        self.log.info("ros2_publishing", vehicle_id=vehicle_id, domain_id=self.domain_id,
                      topics=[estimate_topic(vehicle_id), DIAGNOSTICS_TOPIC], connect=self.ros2_connect)

    def handle(self, item: WorkItem) -> None:
        c = self.counters[item.vehicle_id]
        if item.kind == "ocp":
            rec = OcpEstimate.model_validate_json(item.payload)
            self.latest[item.vehicle_id] = (rec, item.wall)
            self.estimate_pubs[item.vehicle_id].publish(messages.soil_estimate(rec, self.frame_id))
            c.published += 1
            c.last_seq, c.last_stamp, c.last_input_wall = rec.seq, rec.stamp, item.wall
        else:
            h = ServiceHealth.model_validate_json(item.payload)
            if h.service != self.name:  # our own report would describe the publisher of the report
                self.healths[(item.vehicle_id, h.service)] = (h, item.wall)

    def tick(self, now: float) -> None:
        if self.diag_pub is None or now < self._next_diag:
            return
        self._next_diag = now + DIAGNOSTICS_PERIOD_S
        statuses = []
        for vid in self.cfg.vehicle_ids:
            rec, wall = self.latest.get(vid, (None, None))
            statuses.append(messages.estimate_status(vid, rec, None if wall is None else now - wall,
                                                     self.cfg.stale_timeout_s))
            for (v, _svc), (h, hwall) in sorted(self.healths.items()):
                if v == vid:
                    statuses.append(messages.service_status(h, now - hwall, HEALTH_STALE_AFTER_S))
        try:
            self.diag_pub.publish(messages.diagnostic_array(now, statuses))
        except Exception as exc:  # a failed put must not stop the estimates
            self.log.warning("diagnostics_publish_failed", error=f"{type(exc).__name__}: {exc}"[:300])

    def close(self) -> None:
        rmw_zenoh.close_ros(self.node, self.ros_session)
        super().close()
