"""Bag I/O: write and read rosbag2-layout MCAP bags without a running ROS graph.

Layout (what ``ros2 bag record -s mcap`` writes on Jazzy): a directory ``<dir>/`` holding
``metadata.yaml`` (rosbag2 bagfile information, version 9) and ``<dir>_0.mcap`` (profile ``ros2``,
schemas in ``ros2msg`` encoding = the full concatenated ``.msg`` text with its dependencies,
messages CDR-encoded, channel metadata ``offered_qos_profiles`` and ``topic_type_hash``).

Writing (:class:`BagWriter`) is crash safe: the open chunk is closed and the file flushed and
fsync'ed at least every ``flush_period_s`` of message time or wall time, and ``metadata.yaml``
is written at open and rewritten at every flush, so a recording cut off by a crash or power loss
is still a valid rosbag2 directory that loses at most the last flush period.

Reading (:class:`BagReader`) scans the file record by record at open: a bag cut off mid-recording
is read up to its last complete chunk with one :class:`BagWarning`; a corrupt chunk is skipped
with a warning; garbage, empty and missing input raise :class:`BagError` saying what is wrong and
how much was readable. Messages are yielded in log-time order, decoded with the schema stored in
the bag (falling back to the locally installed definition); topics whose type cannot be decoded
are skipped with one warning per topic.

Message definitions come from the installed interface packages (``share/<pkg>/msg/<Name>.msg``
under ``AMENT_PREFIX_PATH``), then from this workspace's source tree (hexapod_msgs), then from an
embedded copy of the standard types the project records (``data/ros_msg_definitions.json``).

No rclpy import: a ROS message instance handed to :meth:`BagWriter.write` is recognised by its
class and encoded field by field like a dict.

The package by job: :mod:`.common` (errors, records, constants), :mod:`.definitions` (message
definition lookup and type hashes), :mod:`.cdr` (message conversion and CDR encoding/decoding),
:mod:`.writer` (:class:`BagWriter`; :mod:`.end_cut` ends its file after a write error), :mod:`.reader`
(:class:`BagReader`), :mod:`.repair` (:func:`recover_bag`, :func:`reindex_bag`),
:mod:`.contents` (:func:`load_bag`, the one loader of a contract bag's topics as typed series,
:class:`BagContents`).
"""
from hexapod_sim.bagio.common import (
    DEFAULT_QOS_PROFILE,
    BagError,
    BagMessage,
    BagWarning,
    MessageEncodeError,
    TopicInfo,
    one_warning,
)
from hexapod_sim.bagio.contents import BagContents, load_bag
from hexapod_sim.bagio.definitions import _EMBEDDED_PATH, message_definition, normalize_type_name, type_hash  # noqa: F401
from hexapod_sim.bagio.reader import BagReader
from hexapod_sim.bagio.repair import recover_bag
from hexapod_sim.bagio.writer import BagWriter, encode_message

__all__ = [
    'BagError', 'BagWarning', 'MessageEncodeError', 'BagMessage', 'TopicInfo', 'BagWriter',
    'BagReader', 'BagContents', 'load_bag', 'message_definition', 'type_hash', 'normalize_type_name',
    'DEFAULT_QOS_PROFILE', 'recover_bag', 'encode_message', 'one_warning',
]
