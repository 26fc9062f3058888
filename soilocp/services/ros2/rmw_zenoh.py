"""ROS 2 on Zenoh the way rmw_zenoh does it (ros2/rmw_zenoh ``docs/design.md``), without ROS.

* Data key of a topic: ``<domain_id>/<fully_qualified_name>/<type_name>/<type_hash>``, the name
  without its leading slash, the type as DDS names it (``sensor_msgs::msg::dds_::Imu_``), the
  type hash RIHS01 (REP-2016) as ``rosbags`` computes it (``Typestore.hash_rihs01``).
* Payload: CDR with its 4-byte encapsulation header (``rosbags`` serialises and deserialises).
* Attachment of every put: sequence number (int64), source timestamp (int64 ns since the Unix
  epoch), GID length (1 byte, 16) and the 16-byte publisher GID, little-endian: exactly the
  zenoh-ext serialisation of ``(Int64, Int64, bytes)``, which is what rmw_zenoh writes with it.
* Graph: liveliness tokens under ``@ros2_lv`` for the node (``NN``) and each publisher (``MP``) or
  subscription (``MS``), so that ``ros2 node list`` / ``ros2 topic list`` / ``ros2 topic info``
  on the robot see them.

Type hashes are those of Jazzy, Kilted and Rolling (equal for every message used here); Humble's
rmw_zenoh has no type hashes (its keys carry ``TypeHashNotSupported``): the reader accepts that,
the writer does not produce it (docs/ros2.md).
"""

from __future__ import annotations

import hashlib
import threading
import time
from functools import lru_cache
from importlib import resources
from typing import Any, Callable, Optional

ADMIN_SPACE = "@ros2_lv"
#: rmw_zenoh's Humble backport puts this where later distributions put the RIHS01 hash
NO_TYPE_HASH = "TypeHashNotSupported"
#: QoS of our endpoints in rmw_zenoh's compact liveliness form (``qos_to_keyexpr``): reliable,
#: volatile, keep last 10 (the defaults are left empty, as rmw_zenoh writes them)
DEFAULT_QOS = "::,10:,:,:,,"
ESTIMATE_TYPE = "soilocp_msgs/msg/SoilEstimate"
DIAGNOSTICS_TYPE = "diagnostic_msgs/msg/DiagnosticArray"


@lru_cache(maxsize=1)
def typestore():
    """ROS 2 Jazzy's message types, plus soilocp_msgs/msg/SoilEstimate from its .msg file."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    ts.register(get_types_from_msg(estimate_msg_definition(), ESTIMATE_TYPE))
    return ts


def estimate_msg_definition() -> str:
    """The text of ``soilocp_msgs/msg/SoilEstimate.msg`` (shipped in this package)."""
    return resources.files("soilocp.services.ros2").joinpath("soilocp_msgs/msg/SoilEstimate.msg").read_text(encoding="utf-8")


@lru_cache(maxsize=None)
def type_hash(ros_type: str) -> str:
    """RIHS01 hash of ``ros_type`` (REP-2016), e.g. ``RIHS01_df668c74...`` for std_msgs/msg/String."""
    return typestore().hash_rihs01(ros_type)


def dds_type_name(ros_type: str) -> str:
    """``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_`` (the name DDS and rmw_zenoh use)."""
    parts = ros_type.split("/")
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"{ros_type!r}: not a ROS 2 type name pkg/msg/Name")
    pkg, kind, name = parts
    return f"{pkg}::{kind}::dds_::{name}_"


def ros_type_name(dds_type: str) -> Optional[str]:
    """Inverse of :func:`dds_type_name`; None for a name that is not of that form."""
    parts = dds_type.split("::")
    if len(parts) != 4 or parts[2] != "dds_" or not parts[3].endswith("_") or len(parts[3]) < 2:
        return None
    return f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"


def check_topic(name: str) -> str:
    """A fully qualified topic name (``/a/b``); ValueError says what is wrong."""
    if not isinstance(name, str) or not name.startswith("/") or name == "/" or name.endswith("/") or "//" in name:
        raise ValueError(f"topic {name!r}: needs a fully qualified ROS 2 name such as /imu/data")
    for tok in name[1:].split("/"):
        if not (tok[0].isalpha() or tok[0] == "_") or not all(c.isalnum() or c == "_" for c in tok):
            raise ValueError(f"topic {name!r}: token {tok!r} is not letters, digits and underscores")
    return name


def topic_key(domain_id: int, topic: str, ros_type: str, hash_: Optional[str] = None) -> str:
    """The data key expression of ``topic`` carrying ``ros_type``."""
    return f"{int(domain_id)}/{check_topic(topic)[1:]}/{dds_type_name(ros_type)}/{hash_ or type_hash(ros_type)}"


def topic_selector(domain_id: int, topic: str) -> str:
    """Every type and hash of ``topic``: the reader checks them itself, to say what does not fit."""
    return f"{int(domain_id)}/{check_topic(topic)[1:]}/*/*"


def split_topic_key(key: str) -> tuple[int, str, str, str]:
    """(domain id, topic, DDS type name, type hash) of a data key; ValueError if it is not one."""
    chunks = key.split("/")
    if len(chunks) < 4 or not chunks[0].isdigit():
        raise ValueError(f"{key!r}: not an rmw_zenoh data key <domain_id>/<name>/<type_name>/<type_hash>")
    return int(chunks[0]), "/" + "/".join(chunks[1:-2]), chunks[-2], chunks[-1]


def mangle(name: str) -> str:
    """rmw_zenoh's mangled name: every ``/`` becomes ``%`` (an empty name or ``/`` is ``%``)."""
    return "%" if name in ("", "/") else name.replace("/", "%")


def node_token(domain_id: int, zid: str, node_id: int, namespace: str, node: str) -> str:
    return f"{ADMIN_SPACE}/{int(domain_id)}/{zid}/{node_id}/{node_id}/NN/%/{mangle(namespace)}/{node}"


def endpoint_token(domain_id: int, zid: str, node_id: int, entity_id: int, kind: str, namespace: str, node: str,
                   topic: str, ros_type: str, hash_: Optional[str] = None, qos: str = DEFAULT_QOS) -> str:
    if kind not in ("MP", "MS"):
        raise ValueError(f"entity kind {kind!r}: MP (publisher) or MS (subscription)")
    return (f"{ADMIN_SPACE}/{int(domain_id)}/{zid}/{node_id}/{entity_id}/{kind}/%/{mangle(namespace)}/{node}/"
            f"{mangle(check_topic(topic))}/{dds_type_name(ros_type)}/{hash_ or type_hash(ros_type)}/{qos}")


def graph_publishers(session, domain_id: int, timeout_s: float = 1.0) -> dict[str, set[str]]:
    """topic -> ROS types of the publishers in the graph (their ``MP`` tokens), as ``ros2 topic list -t``
    would show them; for telling a user which topics exist when a mapped one stays silent."""
    out: dict[str, set[str]] = {}
    for reply in session.liveliness().get(f"{ADMIN_SPACE}/{int(domain_id)}/**", timeout=timeout_s):
        if reply.ok is None:
            continue
        parts = str(reply.ok.key_expr).split("/")
        if len(parts) >= 12 and parts[5] == "MP":
            out.setdefault(parts[9].replace("%", "/"), set()).add(ros_type_name(parts[10]) or parts[10])
    return out


def attachment(seq: int, stamp_ns: int, gid: bytes) -> bytes:
    """rmw_zenoh's attachment: int64 sequence number, int64 source time (ns), GID with its length."""
    from zenoh.ext import Int64, z_serialize

    if len(gid) != 16:
        raise ValueError(f"GID of {len(gid)} bytes: rmw_zenoh's are 16")
    return z_serialize((Int64(seq), Int64(stamp_ns), bytes(gid))).to_bytes()


def parse_attachment(raw: bytes) -> tuple[int, int, bytes]:
    """(sequence number, source time ns, GID) of an rmw_zenoh attachment; ValueError if malformed."""
    import zenoh
    from zenoh.ext import Int64, z_deserialize

    try:
        seq, stamp, gid = z_deserialize(tuple[Int64, Int64, bytes], zenoh.ZBytes(raw))
    except Exception as exc:  # zenoh raises its own error type for short or malformed bytes
        raise ValueError(f"not an rmw_zenoh attachment ({len(raw)} bytes): {exc}") from None
    return int(seq), int(stamp), bytes(gid)


def gid_of(token_key: str) -> bytes:
    """A 16-byte GID unique to an endpoint: a hash of its liveliness key (which holds the session
    id, node and entity ids), as rmw_zenoh derives its GIDs from the entity's identity."""
    return hashlib.blake2b(token_key.encode(), digest_size=16).digest()


class RosPublisher:
    """One ROS 2 publisher: its Zenoh publisher, its ``MP`` token and its attachment sequence."""

    def __init__(self, node: "RosNode", topic: str, ros_type: str, entity_id: int):
        import zenoh

        self.topic, self.ros_type = topic, ros_type
        self.key = topic_key(node.domain_id, topic, ros_type)
        token = endpoint_token(node.domain_id, node.zid, node.node_id, entity_id, "MP", node.namespace, node.name,
                               topic, ros_type)
        self.gid = gid_of(token)
        self._ts = typestore()
        self._encoding = zenoh.Encoding("application/cdr")
        self._pub = node.session.declare_publisher(self.key, congestion_control=zenoh.CongestionControl.BLOCK)
        self._token = node.session.liveliness().declare_token(token)
        self.seq = 0
        self._lock = threading.Lock()

    def publish(self, msg: Any) -> None:
        data = self._ts.serialize_cdr(msg, self.ros_type)
        with self._lock:  # one sequence per publisher, in publication order
            self.seq += 1
            self._pub.put(bytes(data), encoding=self._encoding, attachment=attachment(self.seq, time.time_ns(), self.gid))

    def close(self) -> None:
        for ent in (self._token, self._pub):
            try:
                ent.undeclare()
            except Exception:
                pass


class RosNode:
    """A ROS 2 node on a Zenoh session: its ``NN`` token, then publishers and subscriptions."""

    def __init__(self, session, domain_id: int, name: str, namespace: str = "/"):
        if not name or not all(c.isalnum() or c == "_" for c in name) or name[0].isdigit():
            raise ValueError(f"node name {name!r}: letters, digits and underscores, not starting with a digit")
        self.session, self.domain_id, self.name, self.namespace = session, int(domain_id), name, namespace
        self.zid = str(session.zid())
        self.node_id = 0
        self._entities = 0
        self._closables: list[Any] = []
        self._closables.append(session.liveliness().declare_token(
            node_token(self.domain_id, self.zid, self.node_id, namespace, name)))

    def _next_entity(self) -> int:
        self._entities += 1
        return self._entities

    def publisher(self, topic: str, ros_type: str) -> RosPublisher:
        pub = RosPublisher(self, topic, ros_type, self._next_entity())
        self._closables.append(pub)
        return pub

    def subscription(self, topic: str, ros_types: tuple[str, ...], callback: Callable[[Any], None]) -> None:
        """Subscribe every type and hash of ``topic`` (``callback(sample)`` only enqueues); one ``MS``
        token per accepted type, so the robot's graph shows what this node reads."""
        self._closables.append(self.session.declare_subscriber(topic_selector(self.domain_id, topic), callback))
        for t in ros_types:
            tok = endpoint_token(self.domain_id, self.zid, self.node_id, self._next_entity(), "MS", self.namespace,
                                 self.name, topic, t)
            self._closables.append(self.session.liveliness().declare_token(tok))

    def close(self) -> None:
        for ent in reversed(self._closables):
            try:
                ent.close() if isinstance(ent, RosPublisher) else ent.undeclare()
            except Exception:
                pass
        self._closables.clear()


def close_ros(node: Optional[RosNode], session) -> None:
    """Undeclare a node's tokens and endpoints, then close its session (either may be None)."""
    if node is not None:
        node.close()
    if session is not None:
        try:
            session.close()
        except Exception:  # closing twice, or a session the runtime already tore down
            pass


def ros_session_config(connect: list[str], *, connect_timeout_ms: Optional[int] = None):
    """A client session on the robot's Zenoh router (rmw_zenohd): explicit endpoints, no multicast
    scouting (rmw_zenoh's own default), no TLS (a robot's router listens on plain tcp/)."""
    from soilocp.services.runtime.config import zenoh_config

    return zenoh_config("client", connect, [], multicast=False, connect_timeout_ms=connect_timeout_ms,
                        tls_from_environment=False)


def open_ros_session(connect: list[str], stop: threading.Event, log, retry_s: float = 1.0):
    """Open the session on the robot's router, retrying until it answers or ``stop`` is set (None)."""
    import zenoh

    attempt = 0
    while not stop.is_set():
        attempt += 1
        try:
            session = zenoh.open(ros_session_config(connect, connect_timeout_ms=int(retry_s * 1000)))
        except zenoh.ZError as exc:
            if attempt == 1 or attempt % 10 == 0:
                log.warning("waiting_for_ros2_router", connect=connect, attempt=attempt, error=str(exc)[:200])
            stop.wait(0.1)
            continue
        log.info("ros2_session_open", connect=connect, zid=str(session.zid()), attempts=attempt)
        return session
    return None
