"""corpus/rebuild.py: files come back from a repository at a commit, sha256 checked."""

from __future__ import annotations

import hashlib
import importlib.util
import json
import subprocess
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def rebuild() -> ModuleType:
    spec = importlib.util.spec_from_file_location("rebuild", ROOT / "corpus" / "rebuild.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def git(repo: Path, *args: str) -> str:
    result = subprocess.run(
        ["git", "-C", str(repo), *args], check=True, capture_output=True, text=True
    )
    return result.stdout.strip()


@pytest.fixture
def mirror(tmp_path: Path) -> tuple[Path, str]:
    """DIR/owner+name/repo holding photo.jpg and frames/0.png, 1.png at one commit."""
    repo = tmp_path / "mirrors" / "someone+tags" / "repo"
    (repo / "frames").mkdir(parents=True)
    git(repo, "init", "-q")
    (repo / "photo.jpg").write_bytes(b"jpeg bytes")
    (repo / "frames" / "0.png").write_bytes(b"frame 0")
    (repo / "frames" / "1.png").write_bytes(b"frame 1")
    git(repo, "add", ".")
    git(repo, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "data")
    return tmp_path / "mirrors", git(repo, "rev-parse", "HEAD")


def sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def test_files_are_rebuilt_and_every_sha256_checked(
    rebuild: ModuleType, mirror: tuple[Path, str], tmp_path: Path
) -> None:
    mirrors, commit = mirror
    items = [
        {
            "name": "still",
            "kind": "image",
            "repo": "someone/tags",
            "commit": commit,
            "path": "photo.jpg",
            "sha256": sha(b"jpeg bytes"),
        },
        {
            "name": "walk",
            "kind": "sequence",
            "repo": "someone/tags",
            "commit": commit,
            "paths": ["frames/0.png", "frames/1.png"],
            "sha256s": [sha(b"frame 0"), sha(b"frame 1")],
        },
        {
            "name": "altered",
            "kind": "image",
            "repo": "someone/tags",
            "commit": commit,
            "path": "photo.jpg",
            "sha256": sha(b"other bytes"),
        },
        {
            "name": "elsewhere",
            "kind": "image",
            "repo": "nobody/none",
            "commit": commit,
            "path": "x.jpg",
            "sha256": sha(b""),
        },
    ]
    manifest = tmp_path / "manifest.json"
    manifest.write_text(json.dumps({"format": 1, "items": items}), encoding="utf-8")
    out = tmp_path / "data"
    problems = rebuild.rebuild(manifest, mirrors, out)
    assert (out / "still.jpg").read_bytes() == b"jpeg bytes"
    assert (out / "walk" / "000000.png").read_bytes() == b"frame 0"
    assert (out / "walk" / "000001.png").read_bytes() == b"frame 1"
    assert not (out / "altered.jpg").exists()  # a wrong sha256 writes nothing
    assert len(problems) == 2
    assert problems[0].startswith("altered: photo.jpg has sha256")
    assert problems[1].startswith("elsewhere: no clone or mirror of nobody/none")
    assert (
        rebuild.main(["--mirrors", str(mirrors), "--manifest", str(manifest), "--out", str(out)])
        == 1
    )


def test_the_committed_manifest_is_well_formed() -> None:
    from zenoh_perception_bench.manifest import load_manifest

    items = load_manifest(ROOT / "corpus" / "manifest.json")
    assert len(items) >= 26
    raw = json.loads((ROOT / "corpus" / "manifest.json").read_text(encoding="utf-8"))["items"]
    for item in raw:
        assert len(item["commit"]) == 40
        digests = item["sha256s"] if item["kind"] == "sequence" else [item["sha256"]]
        assert all(len(d) == 64 for d in digests)
        assert item["licence"]
