"""The service's ROS topics on a Zenoh session: plain keys (``bridge``) or a ROS 2 node of its
own on an rmw_zenoh graph (``rmw_zenoh``).

Each topic is an entry of :data:`~zenoh_perception.wire.ros_topics.ROS_TOPICS`. In bridge mode
an entry is its plain key (zenoh-bridge-ros2dds does the rest); with ``bridge_announce`` each
publisher also declares the bridge's own publisher token
(:mod:`zenoh_perception.wire.bridge_liveliness`), so that a bridge offers the topic to ROS, with
its type, before any ROS node subscribes. In rmw_zenoh mode the service
declares the node's liveliness token, and per entry an rmw_zenoh key
(``<domain>/<topic>/<DDS type>/<hash>``, ``*`` in the hash of subscriptions) with its ``MP``
or ``MS`` token; every sample it publishes carries rmw_zenoh's attachment (sequence number,
source timestamp, GID). The formats are built in :mod:`zenoh_perception.wire.rmw_zenoh`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import zenoh

from zenoh_perception.settings import RosTransportKind
from zenoh_perception.settings.sections import Ros
from zenoh_perception.wire.bridge_liveliness import (
    BridgeQos,
    BridgeTokenError,
    Durability,
    History,
    Reliability,
    publisher_token,
)
from zenoh_perception.wire.messages import make_typestore
from zenoh_perception.wire.rmw_zenoh import (
    ANY_HASH,
    PUBLISHER,
    SUBSCRIPTION,
    Attachment,
    NodeInfo,
    Qos,
    fully_qualified,
    gid_of,
    topic_key,
    type_hash,
)
from zenoh_perception.wire.ros_topics import INPUT_ROLES, Direction, RosTopic, ros_topic
from zenoh_perception.wire.stream_keys import Keys, has_wildcard, key_entries, output_key

RMW_ZENOH: str = RosTransportKind.RMW_ZENOH


class TopicPublisher:
    """A Zenoh publisher of one ROS topic; with a GID, each put carries rmw_zenoh's attachment.

    ``put`` may be called from several workers at once (a TF key shared by every stream):
    rmw_zenoh's sequence numbers are taken under a lock.
    """

    def __init__(
        self,
        publisher: zenoh.Publisher,
        *,
        gid: bytes | None = None,
        token: zenoh.LivelinessToken | None = None,
    ) -> None:
        self._publisher = publisher
        self._gid = gid
        self._token = token
        self._seq = 0
        self._seq_lock = threading.Lock()
        self.key = str(publisher.key_expr)

    def put(self, payload: bytes) -> None:
        if self._gid is None:
            self._publisher.put(payload)
            return
        with self._seq_lock:
            self._seq += 1  # rmw_zenoh's first sample is number 1
            seq = self._seq
        attachment = Attachment(seq, time.time_ns(), self._gid).encode()
        self._publisher.put(payload, attachment=attachment)

    @property
    def matched(self) -> bool:
        """Whether a subscriber matches the key now (a Zenoh routing-table look-up)."""
        status = self._publisher.matching_status
        # zenoh-python returns a MatchingStatus (its stubs say a bool): read either
        return bool(getattr(status, "matching", status))

    def declare_matching_listener(
        self, callback: Callable[[zenoh.MatchingStatus], Any]
    ) -> zenoh.MatchingListener[Any]:
        return self._publisher.declare_matching_listener(callback)

    def undeclare(self) -> None:
        _undeclare(self._token, self._publisher)


def _undeclare(*entities: Any) -> None:
    """Undeclare each Zenoh entity given (None: nothing there), the token first."""
    for entity in entities:
        if entity is not None:
            entity.undeclare()


class _Subscription:
    """A subscriber and, on an rmw_zenoh graph, its liveliness token."""

    def __init__(self, subscriber: zenoh.Subscriber[None], token: zenoh.LivelinessToken | None):
        self._subscriber = subscriber
        self._token = token
        self.key = str(subscriber.key_expr)

    def undeclare(self) -> None:
        _undeclare(self._token, self._subscriber)


class RosTransport:
    """Declares the service's ROS topics on ``session`` as ``ros.ros_transport`` says;
    ``topic_keys``: each topic's key, by the name of its setting (``Settings.topic_keys``)."""

    def __init__(self, session: zenoh.Session, ros: Ros, topic_keys: Mapping[str, Keys]) -> None:
        self._session = session
        self._ros = ros
        self._topic_keys = topic_keys
        self.rmw_zenoh = ros.ros_transport is RosTransportKind.RMW_ZENOH
        self.node = NodeInfo(
            domain_id=ros.ros_domain_id,
            session_id=str(session.zid()),
            name=ros.ros_node_name,
            namespace=ros.ros_namespace,
        )
        self._store = make_typestore(ros.ros_package)
        self._next_entity_id = self.node.node_id + 1

    def declare_node(self) -> zenoh.LivelinessToken | None:
        """The node's liveliness token (rmw_zenoh), declared before any of its topics."""
        if not self.rmw_zenoh:
            return None
        return self._session.liveliness().declare_token(self.node.node_token())

    def key(self, role: str, stream: str = "", *, entry: str | None = None) -> str:
        """The Zenoh key (expression) of topic ``role``; of stream ``stream``'s topic when its
        key setting holds ``{stream}``; of ``entry`` (one of its entries) when the setting is
        a list."""
        topic = ros_topic(role)
        bridge_key = output_key(self._setting(topic) if entry is None else entry, stream)
        if not self.rmw_zenoh:
            return bridge_key
        hash_ = ANY_HASH if topic.any_hash else self._hash(topic)
        fq_topic = fully_qualified(self.node.namespace, bridge_key)
        return topic_key(self.node.domain_id, fq_topic, self._type(topic), hash_)

    def keys(self, role: str) -> list[str]:
        """The Zenoh key (expression) of each entry of subscribed topic ``role``'s setting."""
        entries = key_entries(self._topic_keys[ros_topic(role).key_setting])
        return [self.key(role, entry=entry) for entry in entries]

    def topic_of(self, key: str) -> str:
        """The part of ``key`` (a sample's key on one of the service's topics) that its key setting
        matches: the key itself through the bridge; on an rmw_zenoh graph the topic name
        relative to the node's namespace."""
        if not self.rmw_zenoh:
            return key
        chunks = key.split("/")[1:-2]  # neither the domain nor the type and its hash
        namespace = [c for c in self.node.namespace.split("/") if c]
        return "/".join(chunks[len(namespace) :])

    def publisher(self, role: str, *, express: bool = False, stream: str = "") -> TopicPublisher:
        topic = ros_topic(role)
        assert topic.direction is Direction.PUBLISH, role
        publisher = self._session.declare_publisher(
            self.key(role, stream), encoding=zenoh.Encoding.APPLICATION_CDR, express=express
        )
        token = self._token(topic, PUBLISHER, stream)
        if token is None:
            return TopicPublisher(publisher, token=self._bridge_token(topic, publisher))
        return TopicPublisher(
            publisher,
            gid=gid_of(token),
            token=self._session.liveliness().declare_token(token),
        )

    def subscribe(self, role: str, callback: Callable[[zenoh.Sample], Any]) -> list[_Subscription]:
        """Subscribe topic ``role``: a subscription per entry of its setting (one key, or
        each of a list: Zenoh subscribes one key expression at a time).

        On an rmw_zenoh graph a concrete topic's subscription declares its liveliness token
        at once; a topic named by a pattern has none here: a ROS name holds no wildcard (each
        camera topic it matches gets its own once its first frame comes:
        :meth:`stream_subscription`).
        """
        topic = ros_topic(role)
        assert topic.direction is Direction.SUBSCRIBE, role
        subscriptions = []
        for entry in key_entries(self._topic_keys[topic.key_setting]):
            subscriber = self._session.declare_subscriber(self.key(role, entry=entry), callback)
            token = None
            if not has_wildcard(entry):
                fq_topic = fully_qualified(self.node.namespace, entry)
                token = self._token(topic, SUBSCRIPTION, fq_topic=fq_topic)
            declared = None if token is None else self._session.liveliness().declare_token(token)
            subscriptions.append(_Subscription(subscriber, declared))
        return subscriptions

    def stream_subscription(self, key: str) -> zenoh.LivelinessToken | None:
        """On an rmw_zenoh graph, the liveliness token of the node's subscription to the
        concrete topic of ``key`` (a sample's key on a camera topic subscribed by a pattern),
        so that ROS tools list the node among that topic's subscribers; None through the
        bridge, or when no pattern subscription matches ``key``. Undeclare it when the
        stream is forgotten."""
        if not self.rmw_zenoh:
            return None
        concrete = zenoh.KeyExpr(key)
        for role in INPUT_ROLES:
            topic = ros_topic(role)
            for entry in key_entries(self._topic_keys[topic.key_setting]):
                # a concrete entry's token is declared with its subscription
                if not has_wildcard(entry) or not zenoh.KeyExpr(
                    self.key(role, entry=entry)
                ).intersects(concrete):
                    continue
                fq_topic = fully_qualified(self.node.namespace, self.topic_of(key))
                token = self._token(topic, SUBSCRIPTION, fq_topic=fq_topic)
                assert token is not None
                return self._session.liveliness().declare_token(token)
        return None

    def _bridge_token(
        self, topic: RosTopic, publisher: zenoh.Publisher
    ) -> zenoh.LivelinessToken | None:
        """The bridge's publisher token of ``publisher`` (bridge mode, ``bridge_announce``);
        None otherwise, or when its key cannot stand in a token (a stream named with a '§'):
        the bridge then offers the topic once a ROS node subscribes, as without the token."""
        if self.rmw_zenoh or not self._ros.bridge_announce:
            return None
        user_data = f"typehash={self._hash(topic)};"
        try:
            token = publisher_token(
                str(self._session.zid()),
                str(publisher.key_expr),
                self._type(topic),
                _bridge_qos(topic.qos, user_data),
            )
        except BridgeTokenError:
            return None
        return self._session.liveliness().declare_token(token)

    def _setting(self, topic: RosTopic) -> str:
        """The key setting of ``topic``, which holds one key (an output, or an input that is
        not a list)."""
        value = self._topic_keys[topic.key_setting]
        assert isinstance(value, str), (topic.key_setting, value)
        return value

    def _type(self, topic: RosTopic) -> str:
        return topic.type_name(self._ros.ros_package)

    def _hash(self, topic: RosTopic) -> str:
        return type_hash(self._store, self._type(topic))

    def _fq_topic(self, topic: RosTopic, stream: str = "") -> str:
        name = output_key(self._setting(topic), stream)
        return fully_qualified(self.node.namespace, name)

    def _token(
        self, topic: RosTopic, kind: str, stream: str = "", *, fq_topic: str = ""
    ) -> str | None:
        """The liveliness token of a new entity of the node (None in bridge mode), on the
        topic of ``stream`` (or on ``fq_topic``, a fully qualified topic name)."""
        if not self.rmw_zenoh:
            return None
        entity_id, self._next_entity_id = self._next_entity_id, self._next_entity_id + 1
        return self.node.entity_token(
            entity_id,
            kind,
            fq_topic or self._fq_topic(topic, stream),
            self._type(topic),
            # the token names the type's hash even where the key matches every hash
            hash_=self._hash(topic),
            qos=topic.qos,
        )


def _bridge_qos(qos: Qos, user_data: str) -> BridgeQos:
    """An rmw QoS as the bridge's token writes a DDS writer's: Cyclone DDS's numbers, keyless
    (ROS messages have no key), the type hash in USER_DATA as rmw_cyclonedds puts it there."""
    return BridgeQos(
        keyless=True,
        reliability=Reliability[qos.reliability.name],
        durability=Durability[qos.durability.name],
        history=History[qos.history.name],
        depth=qos.depth,
        user_data=user_data,
    )
