"""The whole settings: one frozen dataclass of sections, and the table of flat keys.

A flat key (``tag_key``, ``--tag-key``) is a field of exactly one section; :data:`FLAT`, derived
from the section classes, maps each to its section and field, for the file, the flags, the
status reply and every generic check (bounds, text). Everything else reads a setting by its
typed path (``settings.outputs.tag_key``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any

from zenoh_perception.detect.types import dictionary_names
from zenoh_perception.errors import SettingsError
from zenoh_perception.settings.flat import check_known, coerce
from zenoh_perception.settings.keys import validate_keys
from zenoh_perception.settings.sections import (
    SECTIONS,
    DebugImage,
    DetectorSettings,
    Group,
    Inputs,
    Limits,
    Logs,
    Outputs,
    Ros,
    Selection,
    topic_keys,
)
from zenoh_perception.settings.table import FLAT, section_items
from zenoh_perception.settings.validate import (
    validate_group,
    validate_numbers,
    validate_ros,
    validate_selection,
    validate_streams,
    validate_text,
    validate_tf_prefix,
)
from zenoh_perception.wire.key_advice import FOLLOWS_INPUT
from zenoh_perception.wire.stream_keys import Keys


@dataclass(frozen=True, slots=True)
class Settings:
    """Everything the perception service can be told (see ``config/perception.toml``), by
    section."""

    inputs: Inputs = field(default_factory=Inputs)
    outputs: Outputs = field(default_factory=Outputs)
    group: Group = field(default_factory=Group)
    ros: Ros = field(default_factory=Ros)
    detection: DetectorSettings = field(default_factory=DetectorSettings)
    limits: Limits = field(default_factory=Limits)
    selection: Selection = field(default_factory=Selection)
    debug: DebugImage = field(default_factory=DebugImage)
    logs: Logs = field(default_factory=Logs)

    def __post_init__(self) -> None:
        # every check, in a fixed order (the first failure is raised)
        sections = tuple(getattr(self, name) for name in SECTIONS)
        validate_text(sections)
        validate_keys(self.inputs, self.outputs)
        validate_group(self.inputs, self.group)
        validate_ros(self.ros, self.topic_keys())
        validate_tf_prefix(self.outputs.tf_prefix)
        dictionary_names(self.detection.dictionary)
        validate_numbers(sections, self.selection)
        validate_streams(self.inputs)
        validate_selection(self.selection, self.inputs)
        # the dictionaries as OpenCV spells them, whatever case they were given in
        canonical = ", ".join(dictionary_names(self.detection.dictionary))
        object.__setattr__(self, "detection", replace(self.detection, dictionary=canonical))

    @classmethod
    def from_flat(cls, **values: object) -> Settings:
        """The defaults with ``values`` (flat keys, as in the file) applied, each checked as
        the file's would be."""
        return cls().updated(values)

    def with_flat(self, **values: object) -> Settings:
        """These settings with ``values`` (flat keys) applied, as flags over a file."""
        return self.updated(values)

    def updated(self, values: Mapping[str, object], *, source: str = "settings") -> Settings:
        """These settings with ``values`` (flat keys) applied; every refusal (an unknown key,
        a value of the wrong kind, an invalid one) a SettingsError naming ``source``."""
        check_known(values, source)
        try:
            return replace(self, **self._changed_sections(values))
        except SettingsError as err:
            msg = f"{source}: {err}"
            raise SettingsError(msg) from err

    def _changed_sections(self, values: Mapping[str, object]) -> dict[str, Any]:
        """The sections ``values`` (known flat keys) change, each made anew, by attribute."""
        changes: dict[str, dict[str, object]] = {}
        for name, value in values.items():
            changes.setdefault(FLAT[name].section, {})[name] = coerce(name, value)
        if self.inputs.follows_input and "compressed_input_key" not in values:
            # follows the new input_key
            changes.setdefault("inputs", {})["compressed_input_key"] = FOLLOWS_INPUT
        return {
            section: replace(getattr(self, section), **fields)
            for section, fields in changes.items()
        }

    def topic_keys(self) -> dict[str, Keys]:
        """The key of each ROS topic (:data:`~zenoh_perception.wire.ros_topics.ROS_TOPICS`),
        by the name of the setting that holds it."""
        return topic_keys(self.inputs, self.outputs)

    def as_dict(self) -> dict[str, Any]:
        """Plain-data view by flat key (for the status reply and logs)."""
        data = {
            name: value
            for section in SECTIONS
            for name, value in section_items(getattr(self, section))
        }
        data["tag_sizes"] = {str(k): v for k, v in self.selection.tag_sizes}
        return data


assert tuple(f.name for f in fields(Settings)) == tuple(SECTIONS), "a section is missing"
