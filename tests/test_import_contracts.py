"""The layers as import contracts (``[tool.importlinter]`` in pyproject.toml, run by ``make
lint``): the tree keeps them, and an import planted the wrong way breaks the one it should."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
PACKAGES = ("sim2real", "hardware", "calibration", "s2r_common")
LINT = shutil.which("lint-imports") or shutil.which(
    "lint-imports", path=str(Path(sys.executable).parent)
)
needs_linter = pytest.mark.skipif(
    LINT is None, reason="import-linter is not installed (pip install -e '.[dev]')"
)


def _sources_only(folder: str, names: list[str]) -> set[str]:
    """Everything but Python sources and folders: the contracts read imports alone."""
    return {n for n in names if not (n.endswith(".py") or Path(folder, n).is_dir())} | {
        "__pycache__"
    }


def _tree(tmp_path: Path) -> Path:
    for package in PACKAGES:
        shutil.copytree(ROOT / package, tmp_path / package, ignore=_sources_only)
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    return tmp_path


def _lint(root: Path) -> subprocess.CompletedProcess[str]:
    assert LINT is not None
    env = {**os.environ, "PYTHONPATH": str(root)}
    return subprocess.run(
        [LINT, "--no-cache"], cwd=root, env=env, capture_output=True, text=True, timeout=300
    )


@needs_linter
def test_the_tree_keeps_every_contract(tmp_path: Path) -> None:
    res = _lint(_tree(tmp_path))
    assert res.returncode == 0, res.stdout + res.stderr
    assert "0 broken" in res.stdout


@needs_linter
@pytest.mark.parametrize(
    ("module", "planted", "contract"),
    [
        ("sim2real/deploy/loop.py", "import sim2real.evaluate.core",
         "the deploy runtime imports no offline tool and no CLI"),
        ("sim2real/deploy/session.py", "from sim2real.train import config",
         "the deploy runtime imports no offline tool and no CLI"),
        ("hardware/arm.py", "import sim2real.errors",
         "hardware and calibration never import sim2real"),
        ("calibration/triangulate.py", "import hardware.spec",
         "hardware and calibration never import each other"),
        ("sim2real/export/policy.py", "from sim2real.cli import signals",
         "no library module imports the CLI"),
    ],
)  # fmt: skip
def test_a_wrong_way_import_breaks_its_contract(
    tmp_path: Path, module: str, planted: str, contract: str
) -> None:
    root = _tree(tmp_path)
    path = root / module
    path.write_text(path.read_text() + f"\n\ndef _planted() -> None:\n    {planted}  # noqa\n")
    res = _lint(root)
    assert res.returncode != 0, res.stdout
    assert f"{contract} BROKEN" in res.stdout, res.stdout
    assert module.replace("/", ".").removesuffix(".py") in res.stdout  # names the culprit


def test_every_library_module_is_held_to_the_cli_contract() -> None:
    """A new top-level module of sim2real is a library module: it must be listed."""
    tomllib = pytest.importorskip("tomllib")
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    listed = next(
        set(c["source_modules"]) for c in config["contracts"] if c["id"] == "no-library-imports-cli"
    )
    library = {"hardware", "calibration", "s2r_common"} | {
        f"sim2real.{p.stem}"
        for p in (ROOT / "sim2real").iterdir()
        if (p.suffix == ".py" or (p / "__init__.py").is_file())
        and p.stem not in {"__init__", "__main__", "cli"}
    }
    assert listed == library, (sorted(library - listed), sorted(listed - library))
