"""Deployment files: the zenoh-bridge-ros2dds config, docker-compose.yml, Dockerfile, .dockerignore.

No Docker engine runs here: the compose file is validated by Debian's docker-compose (v1), which
`make system-tools` installs; the Dockerfile and the build context are checked as text.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import json5
import pytest
from ruamel.yaml import YAML

from zenoh_perception.settings import Settings
from zenoh_perception.wire.compressed import COMPRESSED_INPUT_TOPIC
from zenoh_perception.wire.detections import DETECTIONS_TOPIC
from zenoh_perception.wire.tf import TF_TOPIC

ROOT = Path(__file__).resolve().parents[2]
BRIDGE_CONFIG = ROOT / "config" / "zenoh-bridge-ros2dds.json5"
COMPOSE_FILE = ROOT / "docker-compose.yml"
DOCKERFILE = ROOT / "Dockerfile"
DOCKERIGNORE = ROOT / ".dockerignore"

IMAGE_TOPIC = "/zed/left/image"
TAG_TOPIC = "/tag"
DEBUG_IMAGE_TOPIC = "/perception/debug/image/compressed"
COMPRESSED_TOPIC = "/" + str(Settings().topic_keys()[COMPRESSED_INPUT_TOPIC.key_setting])
ROS_TO_ZENOH = (IMAGE_TOPIC, COMPRESSED_TOPIC)
ZENOH_TO_ROS = (
    TAG_TOPIC,
    DEBUG_IMAGE_TOPIC,
    *("/" + str(Settings().topic_keys()[t.key_setting]) for t in (DETECTIONS_TOPIC, TF_TOPIC)),
)
NEVER_ROUTED = (
    "/cmd_vel",
    "/zed/right/image",
    "/zed/left/image_raw",
    "/zed/left/camera_info",
    "/rosout",
    "/parameter_events",
    "/tf_static",
    "/tag_detections",
    "/robot/tag",
    "/perception/debug/image",
    "tag",  # the plugin matches ROS names, which always start with '/'
    "zed/left/image",
)

# Every key of the plugin's `ros2dds` section (zenoh-plugin-ros2dds src/config.rs, a serde struct
# with deny_unknown_fields: any other key stops the bridge at start-up).
PLUGIN_KEYS = frozenset(
    {
        "nodename",
        "namespace",
        "domain",
        "ros_localhost_only",
        "ros_automatic_discovery_range",
        "ros_static_peers",
        "allow",
        "deny",
        "pub_max_frequencies",
        "shm_enabled",
        "transient_local_cache_multiplier",
        "queries_timeout",
        "reliable_routes_blocking",
        "pub_priorities",
        "work_thread_num",
        "max_block_thread_num",
    }
)
INTERFACE_KINDS = (
    "publishers",
    "subscribers",
    "service_servers",
    "service_clients",
    "action_servers",
    "action_clients",
)
#: Passed to the bridge only when set: an empty ROS_AUTOMATIC_DISCOVERY_RANGE stops it.
DISCOVERY_VARIABLES = (
    "ROS_LOCALHOST_ONLY",
    "ROS_AUTOMATIC_DISCOVERY_RANGE",
    "ROS_STATIC_PEERS",
    "CYCLONEDDS_URI",
)
COMPOSE_VARIABLES = (
    "ROS_DISTRO",
    "ROS_DOMAIN_ID",
    "ZENOH_CONNECT",
    "ZENOH_BRIDGE_TAG",
    "REPLAY_BAG",
    *DISCOVERY_VARIABLES,
)


# ---- helpers mirroring the plugin ------------------------------------------------------------


def _plugin_regex(entries: Sequence[str]) -> re.Pattern[str] | None:
    """The allow regex as the plugin builds it: each entry anchored, all joined with '|'.

    An empty list gives no regex at all, which the plugin reads as "nothing of this kind".
    """
    if not entries:
        return None
    return re.compile("|".join(f"^{entry}$" for entry in entries))


def _is_allowed(allow: Mapping[str, Any], kind: str, ros_name: str) -> bool:
    """The plugin's `Allowance::Allow` check for one interface kind (Rust `Regex::is_match`)."""
    regex = _plugin_regex(allow.get(kind, []))
    return regex is not None and regex.search(ros_name) is not None


def _ros_name_to_key(ros_name: str, namespace: str) -> str:
    """The plugin's `ros2_name_to_key_expr`: drop the leading '/', prepend the namespace."""
    if namespace == "/":
        return ros_name[1:]
    return f"{namespace[1:]}/{ros_name[1:]}"


def _endpoint_port(endpoint: str) -> str:
    return endpoint.rsplit(":", 1)[1]


def _option_value(argv: Sequence[str], flag: str) -> str:
    index = list(argv).index(flag)
    return argv[index + 1]


# ---- bridge config -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def bridge_config() -> dict[str, Any]:
    with BRIDGE_CONFIG.open(encoding="utf-8") as stream:
        config: dict[str, Any] = json5.load(stream)
    return config


@pytest.fixture(scope="module")
def plugin(bridge_config: Mapping[str, Any]) -> dict[str, Any]:
    section: dict[str, Any] = bridge_config["plugins"]["ros2dds"]
    return section


@pytest.fixture(scope="module")
def allow(plugin: Mapping[str, Any]) -> dict[str, Any]:
    section: dict[str, Any] = plugin["allow"]
    return section


def test_the_shipped_bridge_config_is_what_bridge_config_writes_for_the_defaults() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "zenoh_perception", "bridge-config"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout == BRIDGE_CONFIG.read_text(encoding="utf-8"), (
        "config/zenoh-bridge-ros2dds.json5 differs from `zenoh-perception bridge-config`: "
        "write it again with `zenoh-perception bridge-config -o config/zenoh-bridge-ros2dds.json5`"
    )


def test_bridge_config_uses_only_keys_the_plugin_accepts(plugin: Mapping[str, Any]) -> None:
    unknown = set(plugin) - PLUGIN_KEYS
    assert not unknown, f"keys the plugin rejects: {sorted(unknown)}"
    assert "deny" not in plugin, "the plugin refuses 'allow' and 'deny' together"
    unknown_kinds = set(plugin["allow"]) - set(INTERFACE_KINDS)
    assert not unknown_kinds, f"unknown interface kinds in allow: {sorted(unknown_kinds)}"


def test_bridge_allow_regexes_compile_as_the_plugin_builds_them(allow: Mapping[str, Any]) -> None:
    for kind in INTERFACE_KINDS:
        entries = allow.get(kind, [])
        assert isinstance(entries, list), f"allow.{kind} must be a list"
        assert all(isinstance(entry, str) for entry in entries), f"allow.{kind}: strings only"
        _plugin_regex(entries)  # raises re.error on an invalid expression


@pytest.mark.parametrize("ros_name", ROS_TO_ZENOH)
def test_ros_publisher_topics_are_routed_to_zenoh(allow: Mapping[str, Any], ros_name: str) -> None:
    assert _is_allowed(allow, "publishers", ros_name)
    assert not _is_allowed(allow, "subscribers", ros_name), "the camera must not flow back to ROS"


@pytest.mark.parametrize("ros_name", ZENOH_TO_ROS)
def test_ros_subscriber_topics_are_routed_from_zenoh(
    allow: Mapping[str, Any], ros_name: str
) -> None:
    assert _is_allowed(allow, "subscribers", ros_name)
    assert not _is_allowed(allow, "publishers", ros_name)


@pytest.mark.parametrize("ros_name", NEVER_ROUTED)
@pytest.mark.parametrize("kind", INTERFACE_KINDS)
def test_other_interfaces_are_not_routed(
    allow: Mapping[str, Any], kind: str, ros_name: str
) -> None:
    assert not _is_allowed(allow, kind, ros_name)


@pytest.mark.parametrize("kind", INTERFACE_KINDS[2:])
def test_no_service_or_action_is_routed(allow: Mapping[str, Any], kind: str) -> None:
    for ros_name in (*ROS_TO_ZENOH, *ZENOH_TO_ROS, "/perception/status", "/anything"):
        assert not _is_allowed(allow, kind, ros_name), f"{kind} lets {ros_name} through"


def test_routed_topics_map_to_the_service_keys(plugin: Mapping[str, Any]) -> None:
    namespace = plugin.get("namespace", "/")
    defaults = Settings()
    assert _ros_name_to_key(IMAGE_TOPIC, namespace) == defaults.inputs.input_key
    assert _ros_name_to_key(TAG_TOPIC, namespace) == defaults.outputs.tag_key
    assert _ros_name_to_key(DEBUG_IMAGE_TOPIC, namespace) == defaults.outputs.debug_image_key
    assert _ros_name_to_key(COMPRESSED_TOPIC, namespace) == defaults.inputs.compressed_input_key
    assert _ros_name_to_key("/perception/detections", namespace) == defaults.outputs.detections_key
    assert _ros_name_to_key("/tf", namespace) == defaults.outputs.tf_key


def test_image_topic_is_never_downsampled_by_the_bridge(plugin: Mapping[str, Any]) -> None:
    # pub_max_frequencies on a large image topic stops its delivery (plugin issue #371).
    # The plugin does not anchor these regexes: any partial match applies.
    for entry in plugin.get("pub_max_frequencies", []):
        regex = entry.split("=", 1)[0]
        assert re.search(regex, IMAGE_TOPIC) is None, f"{entry!r} throttles {IMAGE_TOPIC}"


def test_camera_route_drops_instead_of_blocking_the_camera(plugin: Mapping[str, Any]) -> None:
    assert plugin.get("reliable_routes_blocking") is False


def test_bridge_is_a_router_listening_on_tcp(bridge_config: Mapping[str, Any]) -> None:
    assert bridge_config["mode"] == "router"
    endpoints = bridge_config["listen"]["endpoints"]
    assert endpoints, "the service needs an endpoint to connect to"
    assert all(endpoint.startswith("tcp/") for endpoint in endpoints)
    assert bridge_config["scouting"]["multicast"]["enabled"] is False


# ---- docker-compose ----------------------------------------------------------------------------


def _docker_compose() -> str:
    path = shutil.which("docker-compose")
    if path is None:
        pytest.fail(
            "docker-compose is not installed: it validates docker-compose.yml. "
            "Run `make system-tools` (apt-get install docker-compose) and retry."
        )
    return path


@pytest.fixture(scope="module")
def compose_env(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, str], Path]:
    """An environment without the file's variables or COMPOSE_* overrides, and an empty .env."""
    env = {
        name: value
        for name, value in os.environ.items()
        if name not in COMPOSE_VARIABLES and not name.startswith("COMPOSE_")
    }
    env_file = tmp_path_factory.mktemp("compose") / "empty.env"
    env_file.write_text("", encoding="utf-8")
    return env, env_file


def _run_compose(
    compose_env: tuple[dict[str, str], Path],
    *args: str,
    extra_env: Mapping[str, str] | None = None,
) -> subprocess.CompletedProcess[str]:
    env, env_file = compose_env
    command = [
        _docker_compose(),
        "--file",
        str(COMPOSE_FILE),
        "--project-directory",
        str(ROOT),
        "--env-file",
        str(env_file),
        *args,
    ]
    return subprocess.run(
        command,
        env={**env, **(extra_env or {})},
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def _compose_config(
    compose_env: tuple[dict[str, str], Path], extra_env: Mapping[str, str] | None = None
) -> dict[str, Any]:
    result = _run_compose(compose_env, "config", extra_env=extra_env)
    assert result.returncode == 0, result.stderr
    config: dict[str, Any] = YAML(typ="safe").load(result.stdout)
    return config


@pytest.fixture(scope="module")
def services(compose_env: tuple[dict[str, str], Path]) -> dict[str, Any]:
    resolved: dict[str, Any] = _compose_config(compose_env)["services"]
    return resolved


def test_compose_file_validates(compose_env: tuple[dict[str, str], Path]) -> None:
    result = _run_compose(compose_env, "config", "-q")
    assert result.returncode == 0, f"docker-compose config -q failed:\n{result.stderr}"


def test_compose_services_and_profiles(
    compose_env: tuple[dict[str, str], Path], services: Mapping[str, Any]
) -> None:
    assert set(services) == {"bridge", "perception", "replay"}
    assert "profiles" not in services["bridge"]
    assert "profiles" not in services["perception"]
    assert services["replay"]["profiles"] == ["replay"]
    profiles = _run_compose(compose_env, "config", "--profiles")
    assert profiles.returncode == 0, profiles.stderr
    assert profiles.stdout.split() == ["replay"]


def test_every_service_is_on_the_host_network(services: Mapping[str, Any]) -> None:
    for name, service in services.items():
        assert service.get("network_mode") == "host", f"{name}: DDS discovery needs the host"


def test_bridge_service(services: Mapping[str, Any]) -> None:
    bridge = services["bridge"]
    image, _, tag = bridge["image"].partition(":")
    assert image == "eclipse/zenoh-bridge-ros2dds"
    assert tag and tag != "latest", "pin the bridge version"
    assert bridge["environment"]["ROS_DISTRO"] == "jazzy"
    assert bridge["environment"]["ROS_DOMAIN_ID"] == "0"
    config_in_container = _option_value(bridge["command"], "-c")
    mounts = {
        volume.rsplit(":", 2)[1]: volume.split(":", 1)[0]
        for volume in bridge["volumes"]
        if isinstance(volume, str)
    }
    assert Path(mounts[config_in_container]) == BRIDGE_CONFIG
    assert bridge["restart"] == "unless-stopped"


@pytest.mark.parametrize("distro", ["humble", "jazzy"])
def test_compose_file_validates_for_each_distribution(
    compose_env: tuple[dict[str, str], Path], distro: str
) -> None:
    result = _run_compose(compose_env, "config", "-q", extra_env={"ROS_DISTRO": distro})
    assert result.returncode == 0, result.stderr
    services = _compose_config(compose_env, {"ROS_DISTRO": distro})["services"]
    assert services["bridge"]["environment"]["ROS_DISTRO"] == distro


def test_discovery_variables_reach_the_bridge_only_when_set(
    compose_env: tuple[dict[str, str], Path], services: Mapping[str, Any]
) -> None:
    unset = services["bridge"]["environment"]
    # null: Docker leaves the variable out of the container (the bridge then uses its default)
    assert all(unset[name] is None for name in DISCOVERY_VARIABLES)
    given = {
        "ROS_LOCALHOST_ONLY": "1",
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "ROS_STATIC_PEERS": "192.0.2.7",
        "CYCLONEDDS_URI": "<CycloneDDS><Domain><Tracing/></Domain></CycloneDDS>",
    }
    environment = _compose_config(compose_env, given)["services"]["bridge"]["environment"]
    assert {name: environment[name] for name in DISCOVERY_VARIABLES} == given


def test_ros_domain_id_comes_from_the_environment(
    compose_env: tuple[dict[str, str], Path],
) -> None:
    services = _compose_config(compose_env, {"ROS_DOMAIN_ID": "42"})["services"]
    assert services["bridge"]["environment"]["ROS_DOMAIN_ID"] == "42"


def _connect_endpoints(services: Mapping[str, Any]) -> dict[str, str]:
    perception = services["perception"]
    return {
        "perception command": _option_value(perception["command"], "-e"),
        "perception healthcheck": _option_value(perception["healthcheck"]["test"], "-e"),
        "perception ZENOH_CONNECT": perception["environment"]["ZENOH_CONNECT"],
        "replay command": _option_value(services["replay"]["command"], "-e"),
    }


def test_clients_connect_to_the_bridge_listen_port(
    services: Mapping[str, Any], bridge_config: Mapping[str, Any]
) -> None:
    listen_ports = {_endpoint_port(e) for e in bridge_config["listen"]["endpoints"]}
    for where, endpoint in _connect_endpoints(services).items():
        assert endpoint == "tcp/127.0.0.1:7447", where
        assert _endpoint_port(endpoint) in listen_ports, f"{where}: bridge does not listen there"


def test_one_variable_moves_every_client_together(
    compose_env: tuple[dict[str, str], Path],
) -> None:
    moved = "tcp/192.0.2.10:7448"
    services = _compose_config(compose_env, {"ZENOH_CONNECT": moved})["services"]
    assert set(_connect_endpoints(services).values()) == {moved}


def test_perception_service(services: Mapping[str, Any]) -> None:
    perception = services["perception"]
    assert Path(perception["build"]["context"]) == ROOT
    assert perception["restart"] == "unless-stopped"
    command = perception["command"]
    assert command[0] == "run"
    assert _option_value(command, "--settings") == "/app/config/perception.toml"
    assert _option_value(command, "-m") == "client"
    assert "bridge" in perception["depends_on"]
    test = perception["healthcheck"]["test"]
    assert test[:3] == ["CMD", "zenoh-perception", "status"]
    assert "--timeout" in test


def test_replay_service(services: Mapping[str, Any]) -> None:
    replay = services["replay"]
    command = replay["command"]
    assert command[0] == "replay"
    assert command[1].startswith("/bags/")
    mounts = [volume for volume in replay["volumes"] if isinstance(volume, str)]
    assert any(m.startswith(f"{ROOT / 'bags'}:/bags") for m in mounts), mounts
    assert replay["healthcheck"]["test"] == ["NONE"]


# ---- Dockerfile and build context --------------------------------------------------------------


def _dockerfile_instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) pairs, comments dropped and continuation lines joined."""
    text = DOCKERFILE.read_text(encoding="utf-8")
    lines = [line for line in text.splitlines() if not line.lstrip().startswith("#")]
    joined = re.sub(r"\\\n\s*", " ", "\n".join(lines))
    instructions = []
    for line in joined.splitlines():
        if line.strip():
            word, _, rest = line.strip().partition(" ")
            instructions.append((word.upper(), rest.strip()))
    return instructions


def _dockerignore_excludes(path: str) -> bool:
    """Docker's rule: the last pattern matching the path or one of its parents decides."""
    rules: list[tuple[bool, re.Pattern[str]]] = []
    for raw in DOCKERIGNORE.read_text(encoding="utf-8").splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        negated = line.startswith("!")
        pattern = line.lstrip("!").strip("/")
        translated = (
            re.escape(pattern)
            .replace(r"\*\*/", "(?:.*/)?")
            .replace(r"\*\*", ".*")
            .replace(r"\*", "[^/]*")
            .replace(r"\?", "[^/]")
        )
        rules.append((negated, re.compile(translated)))
    parts = path.split("/")
    candidates = ["/".join(parts[: i + 1]) for i in range(len(parts))]
    excluded = False
    for negated, regex in rules:
        if any(regex.fullmatch(candidate) for candidate in candidates):
            excluded = not negated
    return excluded


def test_dockerfile_uses_a_slim_python_base() -> None:
    instructions = _dockerfile_instructions()
    args = dict(rest.split("=", 1) for word, rest in instructions if word == "ARG" and "=" in rest)
    bases = [rest.split()[0] for word, rest in instructions if word == "FROM"]
    resolved = [re.sub(r"\$\{(\w+)\}", lambda m: args[m.group(1)], base) for base in bases]
    final = resolved[-1]
    match = re.fullmatch(r"python:3\.(\d+)-slim(-\w+)?", final)
    assert match is not None, final
    assert int(match.group(1)) >= 11


def test_dockerfile_runs_as_a_non_root_user() -> None:
    users = [rest for word, rest in _dockerfile_instructions() if word == "USER"]
    assert users, "no USER: the service would run as root"
    user = users[-1].split(":")[0]
    assert user not in {"root", "0"}


def test_dockerfile_healthcheck_queries_the_service_status() -> None:
    checks = [rest for word, rest in _dockerfile_instructions() if word == "HEALTHCHECK"]
    assert len(checks) == 1
    argv = shlex.split(checks[0].split("CMD", 1)[1])
    assert argv[:2] == ["zenoh-perception", "status"]
    assert _option_value(argv, "-e") == "$ZENOH_CONNECT"
    assert _option_value(argv, "--timeout") == "2"
    env = " ".join(rest for word, rest in _dockerfile_instructions() if word == "ENV")
    assert "ZENOH_CONNECT=tcp/127.0.0.1:7447" in env


def test_dockerfile_entrypoint_and_default_command() -> None:
    instructions = dict(_dockerfile_instructions())
    assert instructions["ENTRYPOINT"] == '["zenoh-perception"]'
    assert instructions["CMD"] == '["run", "--settings", "/app/config/perception.toml"]'


def _copied_sources() -> list[str]:
    """Build-context paths of the Dockerfile's COPY instructions (not COPY --from=stage)."""
    sources = []
    for word, rest in _dockerfile_instructions():
        if word == "COPY" and "--from=" not in rest:
            sources.extend(rest.split()[:-1])
    return sources


def test_the_dockerfile_copies_the_package_and_its_settings() -> None:
    sources = _copied_sources()
    assert {"pyproject.toml", "zenoh_perception", "config/perception.toml"} <= set(sources)


@pytest.mark.parametrize("source", _copied_sources())
def test_copied_source_is_in_the_repository(source: str) -> None:
    assert (ROOT / source).exists(), f"COPY {source}: missing, `docker build` would fail"


@pytest.mark.parametrize("source", _copied_sources())
def test_copied_source_is_not_docker_ignored(source: str) -> None:
    assert not _dockerignore_excludes(source), f"COPY {source}: excluded by .dockerignore"
    assert _dockerignore_excludes(f"{source}/__pycache__/x.pyc")


@pytest.mark.parametrize("path", [".git", ".venv", "tests", "bags", "config/secure", ".env"])
def test_build_context_leaves_out_local_files(path: str) -> None:
    assert _dockerignore_excludes(path)
