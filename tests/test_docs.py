"""The repository is self-contained, and every Gymnasium id the README prints works as printed."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
GYM_IDS = re.findall(r'gymnasium\.make\("([^"]+)"', README.read_text(encoding="utf-8"))
# the design notes beside the repository, a developer's paths, the tracker's issue numbers: users have none
OUTSIDE = re.compile(r"shared/|/work/|\bissues? \d+", re.IGNORECASE)


def _product_files() -> list[Path]:
    files = [README, *ROOT.glob("pan1_env/scenarios/*.toml")]
    files += [p for p in (ROOT / "docs").rglob("*") if p.suffix in (".md", ".py")]
    for package in ("pan1_env", "wrappers", "baselines", "examples", "benchmarks"):
        files += (ROOT / package).rglob("*.py")
    return files


def test_no_file_refers_outside_the_repository() -> None:
    offenders = [
        f"{path.relative_to(ROOT)}:{number}: {line.strip()}"
        for path in _product_files()
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if OUTSIDE.search(line)
    ]
    assert not offenders, "\n".join(offenders)


def test_readme_prints_the_gymnasium_ids() -> None:
    assert len(set(GYM_IDS)) >= 4, GYM_IDS


@pytest.mark.parametrize("env_id", sorted(set(GYM_IDS)))
def test_readme_gymnasium_id_works_in_a_fresh_interpreter(env_id: str, tmp_path: Path) -> None:
    code = (
        "import gymnasium\n"
        f"env = gymnasium.make({env_id!r})\n"
        "env.reset(seed=0)\n"
        "env.step(env.action_space.sample())\n"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr


def test_readme_stays_short() -> None:
    # what it is, the two commands, the quickstarts, one results table and links; the rest lives in docs/
    lines = README.read_text(encoding="utf-8").count("\n")
    assert lines <= 250, f"README.md has {lines} lines; move detail into docs/"


def test_relative_links_in_the_docs_lead_to_files() -> None:
    pages = [README, ROOT / "CHANGELOG.md", *(ROOT / "docs").glob("*.md")]
    broken = [
        f"{page.relative_to(ROOT)}: {target}"
        for page in pages
        for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text(encoding="utf-8"))
        if not re.match(r"[a-z]+:|#", target) and not (page.parent / target.split("#")[0]).exists()
    ]
    assert not broken, "\n".join(broken)
