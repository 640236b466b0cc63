"""Outputs are written atomically: a write that fails halfway leaves the old file and no temporary."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pan1_env.experiment import atomic_write


class _Boom(Exception):
    pass


def _listing(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in folder.iterdir()}


@pytest.mark.parametrize("mode", ["wb", "w"])
@pytest.mark.parametrize("error", [_Boom, KeyboardInterrupt])
def test_failed_atomic_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path: Path, mode: str,
                                                                        error: type[BaseException]) -> None:
    path = tmp_path / "metrics.json"
    path.write_bytes(b'{"good": true}\n')
    (tmp_path / "neighbour.txt").write_bytes(b"untouched")
    before = _listing(tmp_path)
    half = b"x" * 100_000 if mode == "wb" else "x" * 100_000

    def write(fh) -> None:
        fh.write(half)
        fh.flush()  # the partial content reaches the temporary file
        raise error("disk full, halfway")

    with pytest.raises(error, match="halfway"):
        atomic_write(path, write, mode=mode)
    assert _listing(tmp_path) == before


def test_failed_atomic_write_creates_nothing(tmp_path: Path) -> None:
    out = tmp_path / "new" / "trajectory.npz"

    def write(fh) -> None:
        np.savez_compressed(fh, q=np.arange(10.0))
        raise _Boom("halfway")

    with pytest.raises(_Boom):
        atomic_write(out, write)
    assert list(out.parent.iterdir()) == []


@pytest.mark.parametrize("existed", [True, False])
def test_atomic_write_replaces_the_file(tmp_path: Path, existed: bool) -> None:
    path = tmp_path / "summary.md"
    if existed:
        path.write_text("old table\n")
    reference = tmp_path / "plain.md"  # what an ordinary open() creates: the mode the umask allows
    reference.write_text("")
    atomic_write(path, lambda fh: fh.write("new table\n"), mode="w")
    assert path.read_text() == "new table\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plain.md", "summary.md"]
    assert path.stat().st_mode == reference.stat().st_mode


def test_write_outputs_keeps_good_metrics_when_serialising_fails(tmp_path: Path) -> None:
    from pan1_env.experiment import RunResult, write_outputs

    good = RunResult({"steps": 1}, {"time": np.zeros(2)})
    paths = write_outputs(good, tmp_path)
    before = _listing(tmp_path)
    bad = RunResult({"steps": 2, "not_json": {1, 2}}, {"time": np.ones(3)})
    with pytest.raises(TypeError):
        write_outputs(bad, tmp_path)
    after = _listing(tmp_path)
    assert set(after) == set(before)  # no temporary left behind
    assert after[paths["metrics"].name] == before[paths["metrics"].name]
