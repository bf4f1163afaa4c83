"""OpenCV's pool told to let its workers sleep, before ``run`` loads OpenCV."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

from zenoh_perception.service.opencv_pool import QUIET_POOL, quiet_opencv_pool

#: Runs ``zenoh-perception run`` in a fresh interpreter until it first imports cv2, and prints
#: what the pool's variables held at that moment (OpenCV reads them when it loads).
_PROBE = textwrap.dedent(
    """
    import json, os, sys
    NAMES = {names!r}

    class AtOpenCv:
        def find_spec(self, name, path=None, target=None):
            if name == "cv2":
                print(json.dumps({{n: os.environ.get(n) for n in NAMES}}), flush=True)
                os._exit(0)
            return None

    sys.meta_path.insert(0, AtOpenCv())
    from zenoh_perception.cli.main import main
    main(["run", "--no-multicast-scouting", "-l", "tcp/127.0.0.1:0"])
    print("null", flush=True)
    """
)


def _pool_when_opencv_loads(env: dict[str, str]) -> dict[str, str | None]:
    probe = _PROBE.format(names=sorted(QUIET_POOL))
    done = subprocess.run(
        [sys.executable, "-c", probe],
        check=False,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    found = json.loads(done.stdout.splitlines()[-1])
    assert found is not None, "run never imported OpenCV"
    return dict(found)


def _without_pool(environ: dict[str, str]) -> dict[str, str]:
    return {k: v for k, v in environ.items() if k not in QUIET_POOL}


def test_run_quiets_the_pool_before_opencv_loads() -> None:
    assert _pool_when_opencv_loads(_without_pool(dict(os.environ))) == QUIET_POOL


def test_the_environments_own_value_wins() -> None:
    env = _without_pool(dict(os.environ))
    env["OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER"] = "2000"
    found = _pool_when_opencv_loads(env)
    assert found["OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER"] == "2000"
    assert found["OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN"] == "0"


def test_quiet_opencv_pool_sets_only_what_is_unset(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in QUIET_POOL:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN", "7")
    quiet_opencv_pool()
    assert os.environ["OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER"] == "0"
    assert os.environ["OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN"] == "7"
