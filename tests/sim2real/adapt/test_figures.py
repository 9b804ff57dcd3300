"""Adapt's stages return typed figures; JSON is made only where it is printed or kept, in the
format ``sim2real adapt --json`` and ``status.json`` have always had (keys, order, values), and a
continued run reads a finished stage back as it was written."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest

from sim2real.adapt.figures import (
    DeployFigures,
    EvaluateFigures,
    ExportFigures,
    FinetuneFigures,
    FitFigures,
    GivenLogsFigures,
    RecordFigures,
    StageResult,
    SysidFigures,
)
from sim2real.adapt.pipeline import STAGES, Adapter, AdaptOptions, summary_table

ZERO = DeployFigures(20, 9, 0.45, (0.2582, 0.6579), 0.0123, 0)
FIGURES: dict[str, Any] = {
    "zero_shot": ZERO,
    "record": RecordFigures(6000, 1200, 60.0, 0.983, ("record/servo.npz", "record/kinematics.npz")),
    "sysid": SysidFigures(
        {
            "time_constant_s": 0.05,
            "max_speed_rad_s": 5.2,
            "deadband_rad": 0.004,
            "latency_s": 0.03,
            "droop_rad": -0.02,
        },
        0.00412,
        {
            "yaw_offset_rad": 0.01,
            "yaw_offset_rad_std": 0.0004,
            "rms_m": 0.0021,
            "n_used": 1180,
            "n_rejected": 20,
        },
    ),
    "fit": FitFigures(
        "fitted.yaml",
        "fitted.dr.yaml",
        "joint_calibration.yaml",
        "ab12cd34",
        (1.5, -2.0, 0.25),
        (0.01, -0.02, 0.0),
        0.004,
        0.012,
        (0.3, 1.1),
    ),
    "finetune": FinetuneFigures("finetune", 2048, 61.5, 120.0, 33.3, None),
    "export": ExportFigures("policy.onnx", 123456, "ab12cd34"),
    "evaluate": EvaluateFigures(20, 19, 0.95, (0.7639, 0.9911), 0.0061, 1, 0.45, (0.2582, 0.6579)),
}
# what each stage's figures have always been, as status.json and the --json lines hold them
JSON = {
    "zero_shot": '{"episodes": 20, "successes": 9, "success_rate": 0.45, "success_wilson95": '
    '[0.2582, 0.6579], "mean_final_distance_m": 0.0123, "watchdog_trips": 0}',
    "record": '{"servo_periods": 6000, "kinematic_periods": 1200, "kinematic_s": 60.0, '
    '"marker_seen_rate": 0.983, "logs": ["record/servo.npz", "record/kinematics.npz"]}',
    "sysid": '{"time_constant_s": 0.05, "max_speed_rad_s": 5.2, "deadband_rad": 0.004, '
    '"latency_s": 0.03, "droop_rad": -0.02, "servo_rms_rad": 0.00412, "yaw_offset_rad": 0.01, '
    '"yaw_offset_rad_std": 0.0004, "rms_m": 0.0021, "n_used": 1180, "n_rejected": 20}',
    "fit": '{"spec": "fitted.yaml", "dr_preset": "fitted.dr.yaml", "joint_calibration": '
    '"joint_calibration.yaml", "fingerprint": "ab12cd34", "link_change_mm": [1.5, -2.0, 0.25], '
    '"joint_offset_rad": [0.01, -0.02, 0.0], "dr_link_half_width_m": 0.004, '
    '"dr_offset_half_width_rad": 0.012, "dr_latency_steps": [0.3, 1.1]}',
    "finetune": '{"run_dir": "finetune", "steps": 2048, "wall_s": 61.5, "budget_s": 120.0, '
    '"steps_per_s": 33.3, "train_success_rate": null}',
    "export": '{"policy": "policy.onnx", "bytes": 123456, "fingerprint": "ab12cd34"}',
    "evaluate": '{"episodes": 20, "successes": 19, "success_rate": 0.95, "success_wilson95": '
    '[0.7639, 0.9911], "mean_final_distance_m": 0.0061, "watchdog_trips": 1, '
    '"zero_shot_success_rate": 0.45, "zero_shot_wilson95": [0.2582, 0.6579]}',
}


@pytest.mark.parametrize("stage", STAGES)
def test_each_stage_keeps_its_json_and_reads_back_as_written(stage: str) -> None:
    assert json.dumps(FIGURES[stage].to_json()) == JSON[stage]
    result = StageResult(stage, FIGURES[stage], 1.25)
    kept = json.loads(json.dumps(result.to_json()))  # through status.json
    assert list(kept)[-1] == "stage_wall_s"
    back = StageResult.from_json(stage, kept)
    assert back.figures == FIGURES[stage] and back.resumed
    assert json.dumps(back.to_json()) == json.dumps({**kept, "resumed": True})


def test_given_logs_nan_and_missing_figures_keep_their_json() -> None:
    given = GivenLogsFigures(("record/servo-0.npz",), ("record/kinematics-0.npz",), ("a.npz",))
    assert json.dumps(given.to_json()) == (
        '{"logs": {"servo": ["record/servo-0.npz"], "kinematics": ["record/kinematics-0.npz"]}, '
        '"given": ["a.npz"]}'
    )
    assert StageResult.from_json("record", StageResult("record", given, 0.5).to_json()).figures == (
        given
    )
    blind = DeployFigures(1, 0, 0.0, (0.0, 0.7935), math.nan, 0)
    assert '"mean_final_distance_m": NaN' in json.dumps(blind.to_json())
    first = EvaluateFigures(**vars(blind))  # no zero-shot stage to compare with
    assert first.to_json()["zero_shot_wilson95"] is None


def test_figures_that_cannot_be_are_refused() -> None:
    with pytest.raises(ValueError, match="3 successes in 2"):
        DeployFigures(2, 3, 1.5, (0.0, 1.0), 0.0, 0)
    with pytest.raises(ValueError, match="unknown adapt stage 'train'"):
        StageResult("train", ZERO, 1.0)
    with pytest.raises(KeyError):
        StageResult.from_json("export", {"policy": "policy.onnx", "stage_wall_s": 0.1})


def test_the_pipeline_keeps_status_and_reports_as_before(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The stages stubbed with the figures above: status.json and the reports of a run, and of
    the run that continues it (every stage read back, ``resumed``), hold the same JSON."""
    for stage in STAGES:
        monkeypatch.setattr(Adapter, f"_stage_{stage}", lambda self, s=stage: FIGURES[s])
    opts = AdaptOptions(policy="reach-ppo", out=tmp_path / "adapt")
    first: list[StageResult] = []
    results = Adapter(opts, first.append).run()
    assert [r.stage for r in first] == list(STAGES) == list(results)
    status = json.loads((opts.out / "status.json").read_text())
    assert status["stages_done"] == list(STAGES)
    for r in first:
        kept = status["figures"][r.stage]
        assert json.dumps(kept) == JSON[r.stage][:-1] + f', "stage_wall_s": {r.stage_wall_s}}}'
        assert not r.resumed and r.to_json() == kept
    again: list[StageResult] = []
    Adapter(opts, again.append).run()
    assert [json.dumps(r.to_json()) for r in again] == [
        json.dumps({**status["figures"][s], "resumed": True}) for s in STAGES
    ]
    table = summary_table(results).splitlines()
    assert table[1].startswith("zero_shot") and "success_rate=0.45" in table[1]
    assert "bytes=123456" in table[6]
