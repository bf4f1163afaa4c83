"""The service's settings: frozen sections, loaded from a TOML file, overridable by flags.

The documented file is ``config/perception.toml``; every field of a section is a key there and
a flag of ``zenoh-perception run`` (``tag_key`` -> ``--tag-key``). Zenoh's own configuration
(mode, endpoints, TLS, ...) is not here: it comes from the Zenoh flags and ``-c`` JSON5 file.

The keys are flat; in the code each is a field of one section (:mod:`.sections`: ``inputs``,
``outputs``, ``group``, ``ros``, ``detection``, ``limits``, ``selection``, ``debug``,
``logs``), and a component takes the sections it uses. :class:`Settings` holds them all;
:data:`FLAT` maps each flat key to its place, for the file, the flags and the status reply;
``Settings.from_flat(tag_key=...)`` makes settings from flat keys as the file would.
The modes (``detector``, ``detector_process``, ``ros_transport``, ``policy``, ``metric``) are
string enums: they read and print as the file writes them.

Validation (every failure is a :class:`SettingsError` naming the setting; the CLI exits 2):

- every number lies within its documented bounds (:data:`BOUNDS`);
- keys are Zenoh key expressions as written (no auto-canonisation); the inputs
  (``input_key``, ``camera_info_key``) may hold wildcards, every key the service publishes,
  serves or declares on must be concrete, and no output may intersect an input;
- an input may be a list of keys (a TOML array, or its flag given once per key): no key
  matched by two entries, each entry a stream name of its own, no more than ``max_streams``;
  with several streams (a wildcard or a list) the outputs hold ``{stream}``;
- ``ros_package`` is a valid ROS package name; ``ros_node_name`` and ``ros_namespace`` are
  valid ROS names, and with ``ros_transport = "rmw_zenoh"`` every key of a ROS topic is a
  relative ROS topic name;
- intrinsics, when given, are plausible (:func:`~zenoh_perception.tags.geometry.check_intrinsics`);
- the settings file is a regular UTF-8 file of at most :data:`MAX_SETTINGS_FILE_BYTES`.
"""

from zenoh_perception.detect.types import DETECTORS, DetectorKind
from zenoh_perception.settings.bounds import (
    DEFAULT_MAX_FRAME_BYTES,
    FRAME_LIMITS_HINT,
    MAX_SETTINGS_FILE_BYTES,
    Bound,
)
from zenoh_perception.settings.keys import check_key
from zenoh_perception.settings.loader import (
    add_settings_arguments,
    load_settings,
    setting_names,
    settings_from_args,
    settings_from_mapping,
)
from zenoh_perception.settings.model import Settings
from zenoh_perception.settings.sections import (
    DEFAULT_INPUT_KEY,
    SECTIONS,
    DetectorProcess,
    RosTransportKind,
    TagSizes,
)
from zenoh_perception.settings.table import BOUNDS, FLAT, check_bound
from zenoh_perception.settings.validate import check_ros_package
from zenoh_perception.tags.selection import Metric, Policy

__all__ = [
    "BOUNDS",
    "DEFAULT_INPUT_KEY",
    "DEFAULT_MAX_FRAME_BYTES",
    "DETECTORS",
    "FLAT",
    "FRAME_LIMITS_HINT",
    "MAX_SETTINGS_FILE_BYTES",
    "SECTIONS",
    "Bound",
    "DetectorKind",
    "DetectorProcess",
    "Metric",
    "Policy",
    "RosTransportKind",
    "Settings",
    "TagSizes",
    "add_settings_arguments",
    "check_bound",
    "check_key",
    "check_ros_package",
    "load_settings",
    "setting_names",
    "settings_from_args",
    "settings_from_mapping",
]
