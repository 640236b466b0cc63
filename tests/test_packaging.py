"""The wheel a user installs (``pip install`` without ``-e``) holds every module and data file of the
package: the editable install the tests run from would hide a package missing from pyproject.toml."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# source folder → where it lands in the wheel (pyproject.toml's package-dir)
SOURCES = {"pan1_env": "pan1_env", "baselines": "pan1_env/baselines", "wrappers": "pan1_env/wrappers"}


def _tracked(folder: str = "") -> list[str]:
    files = subprocess.run(["git", "ls-files", *([folder] if folder else [])], cwd=ROOT, capture_output=True,
                           text=True, check=True)
    return files.stdout.split()


@pytest.mark.slow
def test_the_wheel_holds_every_module_and_data_file(tmp_path) -> None:
    if not (ROOT / ".git").exists():
        pytest.skip("needs the git checkout to list the package's files")
    source = tmp_path / "source"  # the tracked files alone: a build folder left in the checkout would hide a miss
    for name in _tracked():
        if (ROOT / name).is_file():
            (source / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, source / name)
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w",
                            str(tmp_path), str(source)], capture_output=True, text=True, timeout=600)
    assert built.returncode == 0, built.stderr[-2000:]
    wheel = next(tmp_path.glob("pan1_env-*.whl"))
    names = set(zipfile.ZipFile(wheel).namelist())
    expected = [SOURCES[f.split("/")[0]] + f[len(f.split("/")[0]):] for folder in SOURCES for f in _tracked(folder)
                if f.endswith((".py", ".toml", ".zip", ".json"))]
    assert any(name.startswith("pan1_env/kernels/") for name in expected)
    assert any(name.startswith("pan1_env/baselines/pretrained/") for name in expected)
    missing = sorted(name for name in expected if name not in names)
    assert not missing, f"absent from the wheel: {missing}"
