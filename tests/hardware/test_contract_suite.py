"""``hardware.testing``, the Arm contract as a library: the docs' third-party backend passes it
(the very block in docs/hardware.md runs here), and a backend that breaks the contract fails the
check it breaks, in one line naming the check and the value."""

from __future__ import annotations

import contextlib
import io
import re
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import hardware.testing
from hardware.arm import ArmState
from hardware.spec import PWM_SPEC_PATH, load_spec
from hardware.testing import CHECKS, ContractError, check_arm

DOCS = Path(__file__).parents[2] / "docs" / "hardware.md"
TESTED = "<!-- tested: tests/hardware/test_contract_suite.py -->"


def _docs_example() -> str:
    text = DOCS.read_text()
    assert text.count(TESTED) == 1, f"docs/hardware.md should mark one block {TESTED}"
    block = re.search(re.escape(TESTED) + r"\n```python\n(.*?)```", text, re.S)
    assert block is not None, "the marked block is not a python code block"
    return block.group(1)


@pytest.fixture(scope="module")
def example() -> dict[str, Any]:
    """The docs' example, run as written (its check_arm raises if a check fails)."""
    namespace: dict[str, Any] = {"__name__": "docs_example"}
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(_docs_example(), str(DOCS), "exec"), namespace)
    namespace["printed"] = out.getvalue()
    return namespace


def test_the_docs_backend_passes_every_check(example: dict[str, Any]) -> None:
    report = example["report"]
    assert report.ok and [r.name for r in report.results] == list(CHECKS)
    printed = example["printed"].splitlines()
    assert printed[0] == f"MemoryArm: {len(CHECKS)}/{len(CHECKS)} contract checks passed"
    shown = [line.lstrip("# ") for line in _docs_example().splitlines() if "#   ok" in line]
    assert shown
    for line in shown:  # the output the docs show is the output
        assert any(p.strip().startswith(line.split(" (")[0]) for p in printed), line
    print(example["printed"])


def test_the_library_imports_no_test_framework() -> None:
    source = Path(hardware.testing.__file__).read_text()
    assert not re.search(r"^\s*(import|from)\s+(pytest|unittest|hypothesis)", source, re.M)


def _broken(example: dict[str, Any], **hooks: Any) -> type:
    return type("Broken", (example["MemoryArm"],), hooks)


def _torque_stays_on(self: Any, on: bool, hold_rad: np.ndarray | None) -> None:
    self.torque = True  # ignores "off": the arm never lets go
    if on and hold_rad is not None:
        self.joints = hold_rad.copy()


def test_an_arm_that_never_lets_go_fails_the_torque_checks(example: dict[str, Any]) -> None:
    spec = load_spec()
    arm_type = _broken(example, _set_torque=_torque_stays_on)
    with pytest.raises(ContractError) as info:
        check_arm(lambda: arm_type(spec), example["MemoryProbe"], spec,
                  only=["is_an_arm", "context_manager", "disable_and_close_release_torque"])  # fmt: skip
    report = info.value.report
    assert report is not None
    assert [r.name for r in report.failed] == [
        "context_manager",
        "disable_and_close_release_torque",
    ]
    assert report.results[0].passed
    errors = [r.error for r in report.failed]
    assert errors == [
        "context_manager: the torque is still on after leaving the with block",
        "disable_and_close_release_torque: the torque is on after disable()",
    ]
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith("check_arm: 2 of 3 failed: context_manager: the torque is still on")
    assert "FAIL context_manager" in str(report) and "ok   is_an_arm" in str(report)


def _misreports(self: Any, targets_rad: np.ndarray) -> np.ndarray:
    self.applied.append(targets_rad + 0.01)  # applies one thing, reports another
    if self.torque:
        self.joints = targets_rad + 0.01
    return targets_rad


def test_sent_must_be_what_the_backend_applied(example: dict[str, Any]) -> None:
    spec = load_spec()
    arm_type = _broken(example, _send_targets=_misreports)
    report = check_arm(lambda: arm_type(spec), example["MemoryProbe"],
                       only=["sent_is_received"], raise_on_failure=False)  # fmt: skip
    assert not report.ok
    (error,) = [r.error for r in report.failed]
    assert error is not None
    assert re.fullmatch(
        r"sent_is_received: the backend applied \[[-\d. ]+\] rad is not within 1e-06 rad of "
        r"\[[-\d. ]+\]",
        error,
    ), error


def test_a_clock_that_runs_back_and_a_backend_error_fail_their_checks(
    example: dict[str, Any],
) -> None:
    spec = load_spec()
    ticks = iter(range(1000, 0, -1))

    def backwards(self: Any) -> ArmState:
        return ArmState(self.joints.copy(), float(next(ticks)))

    def unplugged(self: Any, targets_rad: np.ndarray) -> np.ndarray:
        raise OSError("the port went away\nsecond line")

    report = check_arm(lambda: _broken(example, _read_state=backwards)(spec),
                       example["MemoryProbe"], only=["state"], raise_on_failure=False)  # fmt: skip
    assert report.failed[0].error is not None
    assert report.failed[0].error.startswith("state: timestamps [")
    assert report.failed[0].error.endswith("run back")
    report = check_arm(lambda: _broken(example, _send_targets=unplugged)(spec),
                       example["MemoryProbe"], only=["home"], raise_on_failure=False)  # fmt: skip
    assert [r.error for r in report.failed] == ["home: OSError: the port went away"]


def test_the_spec_and_the_names_are_checked(example: dict[str, Any]) -> None:
    spec, pwm = load_spec(), load_spec(PWM_SPEC_PATH)
    with pytest.raises(ContractError, match=r"check_arm: 1 of 1 failed: spec: the arm's spec"):
        check_arm(lambda: example["MemoryArm"](spec), example["MemoryProbe"], pwm, only=["home"])
    with pytest.raises(ValueError, match="unknown contract checks \\['homing'\\]"):
        check_arm(lambda: example["MemoryArm"](spec), example["MemoryProbe"], only=["homing"])


def test_each_check_closes_its_arm(example: dict[str, Any]) -> None:
    spec = load_spec()
    made: list[Any] = []

    def make() -> Any:
        made.append(example["MemoryArm"](spec))
        return made[-1]

    t0 = time.monotonic()
    check_arm(make, example["MemoryProbe"], only=["home", "wrong_shape_refused"])
    assert len(made) == 2 and not any(a.is_connected for a in made)
    assert time.monotonic() - t0 < 30.0


def _reads_its_command(self: Any) -> ArmState:
    """A bare PWM servo: the reading is the last command, not the horn."""
    sent = getattr(self, "sent", self.joints)
    return ArmState(sent.copy(), time.monotonic(), measured=np.zeros(len(sent), bool))


def _horn_moving(step_rad: float) -> Any:
    def send(self: Any, targets_rad: np.ndarray) -> np.ndarray:
        self.applied.append(targets_rad.copy())
        self.sent = targets_rad.copy()
        if self.torque:  # the horn follows the command, at most step_rad per frame
            self.joints = self.joints + np.clip(targets_rad - self.joints, -step_rad, step_rad)
        return targets_rad

    return send


def test_a_horn_that_lags_its_reading_is_held_until_it_arrives(
    example: dict[str, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The hold after ``move_to`` waits on progress, not on a count of holds or a wall-clock
    budget an idle machine meets: this horn needs far more holds than the reading does (the
    holds are quickened here so the test is short; the count is what matters)."""
    monkeypatch.setattr(hardware.testing, "HOLD_PERIOD_S", 0.0)
    spec = load_spec()
    arm_type = _broken(example, _read_state=_reads_its_command, _send_targets=_horn_moving(0.002))
    made: list[Any] = []

    def make() -> Any:
        made.append(arm_type(spec))
        return made[-1]

    report = check_arm(make, example["MemoryProbe"], only=["moves_to_a_pose"])
    assert report.ok
    assert len(made[0].applied) > 200  # the old budget held 100 times at most


def test_a_horn_that_never_arrives_fails_after_the_settle_time(example: dict[str, Any]) -> None:
    spec = load_spec()
    arm_type = _broken(example, _read_state=_reads_its_command, _send_targets=_horn_moving(0.0))
    t0 = time.monotonic()
    report = check_arm(lambda: arm_type(spec), example["MemoryProbe"], settle_timeout_s=0.2,
                       only=["moves_to_a_pose"], raise_on_failure=False)  # fmt: skip
    (error,) = [r.error for r in report.failed]
    assert error is not None
    assert error.startswith("moves_to_a_pose: the true position [") and "within 0.06 rad" in error
    assert time.monotonic() - t0 < 30.0  # a bound on a hang, not a timing
