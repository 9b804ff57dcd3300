"""Shared pieces for the viewer's tests: real deploy logs (one mock run with its frames, one sim
run), and counts read back from a ``.rrd`` with Rerun's own dataframe reader."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from sim2real.cli.main import main

pytest.importorskip("rerun", reason="the 'view' extra (rerun-sdk) is not installed")


@pytest.fixture(scope="session")
def mock_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """``sim2real deploy reach-ppo --backend mock``, one 25-period episode: its log and its
    frames (the dataset the same deploy recorded, one camera pair a period)."""
    out = tmp_path_factory.mktemp("mock")
    log, frames = out / "mock.npz", out / "frames"
    args = [
        "deploy", "reach-ppo", "--backend", "mock", "--episodes", "1", "--log", str(log),
        "--record-dataset", str(frames), "--watchdog-s", "10", "--start-timeout", "60", "--json",
        "--camera-fps", "20",  # a frame a period, as the dataset keeps them: less CPU
        "--steps", "25",  # half an episode: every entity still shows, in half the arm time
    ]  # fmt: skip
    assert main(args) == 0
    return log, frames


@pytest.fixture(scope="session")
def sim_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    log = tmp_path_factory.mktemp("sim") / "sim.npz"
    args = ["deploy", "reach-ppo", "--backend", "sim", "--episodes", "1", "--log", str(log),
            "--sim-clock", "lockstep", "--json"]  # fmt: skip
    assert main(args) == 0
    return log


def read_counts(path: Path, index: str = "period") -> dict[str, int]:
    """``"<entity>:<Component>"`` -> rows on ``index`` where it has data, read back with
    ``rerun.dataframe`` (static data and indicator components left out)."""
    import rerun.dataframe as rdf

    recording = rdf.load_recording(str(path))
    table = recording.view(index=index, contents="/**").select().read_all()
    static = {
        f"{c.entity_path}:{c.component_name.rsplit('.', 1)[-1]}"
        for c in recording.schema().component_columns()
        if c.is_static
    }
    return {
        name: len(table) - table.column(name).null_count
        for name in table.column_names
        if name.startswith("/") and "Indicator" not in name and name not in static
    }


@pytest.fixture
def rrd_counts() -> Callable[..., dict[str, int]]:
    return read_counts
