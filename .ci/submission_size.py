#!/usr/bin/env python3
"""How big the commits since BASE are, as a submission counts them.

A stop submits every commit on main since the last landed one; it is refused whole when the
commits pack to more than 512 MiB, or when their diffs added up as text exceed 256 MiB (a file
added in one commit and removed in a later one counts twice). Run states and snapshots under
``runs/`` are the usual culprits: commit ``last.pt`` once or twice a session, not every hour.

    python .ci/submission_size.py BASE        # BASE: the last landed commit (e.g. origin/main)

Prints the packed size, the diff total and the ten largest blobs added; exits 1 over a limit.
"""
from __future__ import annotations

import subprocess
import sys

PACK_LIMIT = 512 * 2**20
DIFF_LIMIT = 256 * 2**20


def _git(*args: str, data: bytes | None = None) -> bytes:
    return subprocess.run(["git", *args], input=data, check=True, capture_output=True).stdout


def main(base: str) -> int:
    objects = _git("rev-list", "--objects", f"{base}..HEAD")
    packed = len(_git("pack-objects", "--stdout", "-q", data=objects)) if objects.strip() else 0
    diff_total, added = 0, []
    for commit in _git("rev-list", f"{base}..HEAD").decode().split():
        # Text diffs count as their patch text; a binary file counts as its patch in git's binary
        # form (base85: ~1.25x, with the old blob too when it is modified), and at least its whole
        # new blob (a 244 MiB reading of the new-blob rule alone was refused as over 256 MiB).
        patch = _git("show", "--format=", "--no-color", "--no-ext-diff", commit)
        binary = _git("show", "--format=", "--no-color", "--no-ext-diff", "--binary", commit)
        diff_total += max(len(binary), len(patch))
        for line in _git("diff-tree", "-r", "--no-commit-id", "--root", commit).decode().splitlines():
            meta, path = line.split("\t", 1)
            new_sha = meta.split()[3]
            if set(new_sha) == {"0"}:
                continue
            size = int(_git("cat-file", "-s", new_sha))
            if b"Binary files" in patch and path.encode() in patch and len(binary) <= len(patch):
                diff_total += size
            added.append((size, path, commit[:8]))
    mib = 2**20
    print(f"packed {packed / mib:.1f} MiB of {PACK_LIMIT // mib}; diffs {diff_total / mib:.1f} MiB of {DIFF_LIMIT // mib}")
    for size, path, commit in sorted(added, reverse=True)[:10]:
        print(f"  {size / mib:7.1f} MiB  {commit}  {path}")
    return 1 if packed > PACK_LIMIT or diff_total > DIFF_LIMIT else 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    sys.exit(main(sys.argv[1]))
