"""Live view: a Foxglove WebSocket server (foxglove-sdk) with the topics a bag would hold.

Open ``ws://127.0.0.1:PORT`` in the Foxglove app ("Open connection" -> Foxglove WebSocket) and
add a 3D panel: the robot model comes from ``/robot_description`` (URDF), its pose from ``/tf``
and ``/tf_static``; plots and the raw messages panel show ``/joint_states`` and the
ground-detection telemetry ``/ground_detection``. Messages are sent with the schemas and CDR
bytes of the recording (``ros2msg`` / ``cdr``, exactly what :class:`hexapod_sim.bagio.recorder.Recorder`
writes), so the live view and a bag look the same in Foxglove.

The server binds 127.0.0.1 only. Latched topics (``/robot_description``, ``/tf_static``) are
sent again to every client that subscribes to them, as a transient-local publisher would.
"""
from __future__ import annotations

import threading

from hexapod_model import contract
from hexapod_sim.bagio import message_definition, normalize_type_name

DEFAULT_PORT = 8765
HOST = '127.0.0.1'
# What the live view serves: the robot (model and transforms), its joints, the controller's
# telemetry and health; not the 1 kHz /clock or the goals.
LIVE_TOPICS = (contract.ROBOT_DESCRIPTION, contract.TF_STATIC, contract.TF, contract.JOINT_STATES,
               contract.GROUND_DETECTION, contract.SWING_DOWN, contract.DIAGNOSTICS, contract.SIM_TRUTH_POSE,
               contract.SIM_TRUTH_CONTACTS, contract.IMU, contract.POWER, contract.ODOM, contract.TERRAIN)
LATCHED = (contract.ROBOT_DESCRIPTION, contract.TF_STATIC)
# Channels carry the names a bag stores (absolute: '/joint_states', '/robot_description'), whatever
# namespace the nodes run in, so the live view and a recording open with the same layout.
_LIVE = {contract.bag_topic(t) for t in LIVE_TOPICS}
_LATCHED = {contract.bag_topic(t) for t in LATCHED}


class LiveViewError(RuntimeError):
    """The live view cannot start (foxglove-sdk missing, port in use); the message says why."""


class LiveView:
    """Foxglove WebSocket server on ``127.0.0.1:port`` (0: a free port, see :attr:`port`)."""

    def __init__(self, port: int = DEFAULT_PORT, name: str = 'hexapod'):
        try:
            import foxglove
        except ImportError:
            raise LiveViewError('the live view needs foxglove-sdk (pinned in requirements/py.txt; '
                                'run ./hexapod setup)') from None
        if not isinstance(port, int) or not 0 <= port <= 65535:
            raise LiveViewError(f'live view port must be 0..65535, got {port!r}')
        self._fg = foxglove
        self._ctx = foxglove.Context()
        self._lock = threading.Lock()
        self._channels: dict[str, object] = {}
        self._latched: dict[str, tuple[bytes, int]] = {}
        self._resend: set[str] = set()
        view = self

        class Listener(foxglove.ServerListener):
            def on_subscribe(self, client, channel) -> None:   # a latched topic's last message again
                if channel.topic in _LATCHED:
                    with view._lock:
                        view._resend.add(channel.topic)

        # every channel exists before a client connects: one advertisement, no subscription race
        for topic in LIVE_TOPICS:
            self._channel(topic, contract.MSG_TYPES[topic])
        try:
            self._server = foxglove.start_server(name=name, host=HOST, port=port, context=self._ctx,
                                                 server_listener=Listener())
        except Exception as exc:            # noqa: BLE001 - the SDK raises its own error types
            raise LiveViewError(f'cannot serve the live view on {HOST}:{port}: {exc}') from None
        self.port = int(self._server.port)

    @property
    def url(self) -> str:
        return f'ws://{HOST}:{self.port}'

    def _channel(self, topic: str, msg_type: str):
        topic = contract.bag_topic(topic)
        ch = self._channels.get(topic)
        if ch is None:
            full = normalize_type_name(msg_type)
            schema = self._fg.Schema(name=full, encoding='ros2msg', data=message_definition(full).encode())
            ch = self._fg.Channel(topic, schema=schema, message_encoding='cdr', context=self._ctx)
            self._channels[topic] = ch
        return ch

    def log(self, topic: str, msg_type: str, cdr: bytes, t_ns: int) -> None:
        """Send one CDR-encoded message on the bag's name of ``topic`` (topics outside
        :data:`LIVE_TOPICS` are not served)."""
        topic = contract.bag_topic(topic)
        if topic not in _LIVE:
            return
        with self._lock:
            ch = self._channel(topic, msg_type)
            if topic in _LATCHED:
                self._latched[topic] = (msg_type, cdr, t_ns)
            resend = [self._latched[t] + (t,) for t in self._resend if t in self._latched]
            self._resend.clear()
        ch.log(cdr, log_time=t_ns)
        for msg_type_, data, t, topic_ in resend:
            self._channel(topic_, msg_type_).log(data, log_time=t)

    def close(self) -> None:
        self._server.stop()
