"""Rebuild the corpus's data folder from clones or mirrors of the repositories it names.

    python corpus/rebuild.py --mirrors DIR [--manifest corpus/manifest.json] [--out corpus/data]

For each item of the manifest the file is read from its repository at its commit
(``git cat-file blob COMMIT:PATH``, which works on bare mirrors and on clones), its sha256 is
checked, and it is written to ``OUT/<name><ext>`` (a sequence: ``OUT/<name>/000000<ext>``, ...).
A repository ``owner/name`` is looked for as ``DIR/owner+name/repo``, ``DIR/owner+name``,
``DIR/owner/name``, ``DIR/owner/name.git`` or ``DIR/name``. Exit 1 when a file is missing or
its sha256 differs (nothing is written for it); 0 when every file is in place.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
from pathlib import Path, PurePosixPath
from typing import Any

HERE = Path(__file__).resolve().parent


def repository(mirrors: Path, repo: str) -> Path | None:
    """The git directory or work tree of ``repo`` under ``mirrors``, if there is one."""
    owner, _, name = repo.partition("/")
    for candidate in (
        mirrors / f"{owner}+{name}" / "repo",
        mirrors / f"{owner}+{name}",
        mirrors / owner / name,
        mirrors / owner / f"{name}.git",
        mirrors / name,
    ):
        if candidate.is_dir():
            return candidate
    return None


def blob(git_dir: Path, commit: str, path: str) -> bytes | None:
    """The bytes of ``path`` at ``commit``, or None when git does not have them."""
    result = subprocess.run(
        ["git", "-C", str(git_dir), "cat-file", "blob", f"{commit}:{path}"],
        capture_output=True,
        check=False,
    )
    return result.stdout if result.returncode == 0 else None


def targets(item: dict[str, Any], out: Path) -> list[tuple[str, str, Path]]:
    """(path in the repository, sha256, file to write) for each file of ``item``."""
    name = str(item["name"])
    if item["kind"] == "sequence":
        return [
            (path, digest, out / name / f"{index:06d}{PurePosixPath(path).suffix.lower()}")
            for index, (path, digest) in enumerate(zip(item["paths"], item["sha256s"], strict=True))
        ]
    suffix = PurePosixPath(item["path"]).suffix.lower()
    return [(item["path"], item["sha256"], out / f"{name}{suffix}")]


def rebuild(manifest: Path, mirrors: Path, out: Path) -> list[str]:
    """Write every file of the manifest under ``out``; the problems, one line each."""
    items = json.loads(manifest.read_text(encoding="utf-8"))["items"]
    problems: list[str] = []
    for item in items:
        git_dir = repository(mirrors, item["repo"])
        if git_dir is None:
            problems.append(f"{item['name']}: no clone or mirror of {item['repo']} in {mirrors}")
            continue
        for path, digest, target in targets(item, out):
            data = blob(git_dir, item["commit"], path)
            if data is None:
                problems.append(f"{item['name']}: {item['repo']}@{item['commit']}:{path} missing")
                continue
            actual = hashlib.sha256(data).hexdigest()
            if actual != digest:
                problems.append(f"{item['name']}: {path} has sha256 {actual}, not {digest}")
                continue
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(data)
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    parser.add_argument("--mirrors", type=Path, required=True, metavar="DIR")
    parser.add_argument("--manifest", type=Path, default=HERE / "manifest.json")
    parser.add_argument("--out", type=Path, default=HERE / "data")
    args = parser.parse_args(argv)
    problems = rebuild(args.manifest, args.mirrors, args.out)
    for line in problems:
        print(line, file=sys.stderr)
    total = len(json.loads(args.manifest.read_text(encoding="utf-8"))["items"])
    print(f"{total} items, {len(problems)} problems; data in {args.out}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
