"""Progress bars draw on a terminal only: never in CI, never into a pipe or a file."""

from __future__ import annotations

import io
import os
from collections.abc import Iterator

import pytest

from sim2real.progress import progress_bar, progress_enabled


@pytest.fixture
def tty() -> Iterator[io.TextIOWrapper]:
    """A real terminal: the follower end of a pseudo-terminal."""
    leader, follower = os.openpty()
    stream = os.fdopen(follower, "w")
    yield stream
    stream.close()
    os.close(leader)


def test_draws_on_a_terminal_outside_ci(
    tty: io.TextIOWrapper, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("CI", raising=False)
    assert progress_enabled(True, tty)
    assert not progress_enabled(False, tty)  # --no-progress / --json


@pytest.mark.parametrize("ci", ["true", "1", "yes"])
def test_quiet_in_ci(tty: io.TextIOWrapper, monkeypatch: pytest.MonkeyPatch, ci: str) -> None:
    monkeypatch.setenv("CI", ci)
    assert not progress_enabled(True, tty)


def test_ci_false_is_not_ci(tty: io.TextIOWrapper, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CI", "false")
    assert progress_enabled(True, tty)


def test_quiet_into_a_pipe_or_file(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("CI", raising=False)
    read_fd, write_fd = os.pipe()
    with os.fdopen(write_fd, "w") as pipe:
        assert not progress_enabled(True, pipe)
    os.close(read_fd)
    assert not progress_enabled(True, io.StringIO())


def test_a_disabled_bar_writes_nothing(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("CI", "true")
    with progress_bar(3, "work", "item") as bar:
        for _ in range(3):
            bar.update(1)
    out, err = capsys.readouterr()
    assert out == "" and err == ""
