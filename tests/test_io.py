"""Atomic result files: complete or absent, and readable like any other file."""
import json
import os
import stat

import pytest

from r2pac_jax.io import atomic_write_json, atomic_write_text


def test_atomic_write_replaces_whole_file_with_umask_mode(tmp_path):
    old = os.umask(0o022)
    try:
        p = atomic_write_json(tmp_path / "sub" / "r.json", {"a": 1})
    finally:
        os.umask(old)
    assert json.loads(p.read_text()) == {"a": 1}
    assert stat.S_IMODE(p.stat().st_mode) == 0o644
    atomic_write_text(p, "second\n")
    assert p.read_text() == "second\n"
    assert [q.name for q in p.parent.iterdir()] == ["r.json"]  # no temporary file left


def test_failed_write_leaves_the_old_file(tmp_path):
    p = atomic_write_text(tmp_path / "r.json", "old\n")
    with pytest.raises(TypeError, match="not JSON serialisable"):
        atomic_write_json(p, {"x": object()})
    assert p.read_text() == "old\n"
    assert [q.name for q in tmp_path.iterdir()] == ["r.json"]
