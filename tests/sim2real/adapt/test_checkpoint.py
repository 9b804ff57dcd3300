"""Where adapt's fine-tune starts: a shipped policy's checkpoint rebuilds exactly the shipped
policy (actor and normalisation), the fine-tune run carries the fitted spec and trains on; a
policy without a checkpoint is refused in one line."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from hardware.spec import load_spec
from sim2real.adapt.checkpoint import prepare_finetune_dir, resolve_source
from sim2real.errors import Sim2RealError
from sim2real.policies import shipped
from sim2real.randomization import load_preset
from sim2real.train.rundir import RunDir

SPEC = load_spec()


def onnx_only_shipping(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A shipping folder whose one policy is ONNX only (a card without ``checkpoint``), as the
    policies were before they carried checkpoints."""
    import json
    import shutil

    import sim2real.policies as policies

    src = shipped()["reach-ppo"]
    folder = tmp_path / "shipped"
    folder.mkdir()
    shutil.copy(src.path, folder / "old-ppo.onnx")
    card = json.loads((src.path.with_suffix(".json")).read_text())
    card.pop("checkpoint")
    card["file"] = "old-ppo.onnx"
    (folder / "old-ppo.json").write_text(json.dumps(card))
    monkeypatch.setattr(policies, "SHIPPED_DIR", folder)
    return folder


@pytest.mark.parametrize(
    ("ref", "says"),
    [
        ("old-ppo", "carries no SB3 checkpoint"),
        ("no-such-policy", "does not exist"),
        (str(shipped()["reach-ppo"].path), "is an exported file"),
    ],
)
def test_a_policy_without_a_checkpoint_is_refused_in_one_line(
    ref: str, says: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    onnx_only_shipping(tmp_path, monkeypatch)
    with pytest.raises(Sim2RealError, match=says) as info:
        resolve_source(ref)
    assert "\n" not in str(info.value)


def test_the_shipped_checkpoint_is_the_shipped_policy_and_fine_tunes(tmp_path: Path) -> None:
    from sim2real.evaluate.parity import max_action_diff, sample_observations
    from sim2real.train.runner import resume

    src = resolve_source("reach-ppo")
    assert src.steps > 0 and src.vecnormalize_stats is not None
    run = tmp_path / "finetune"
    dr = load_preset("default")
    # a spec that differs in one link: the run must carry its fingerprint, not the source's
    spec = dataclasses.replace(
        SPEC, links=dataclasses.replace(SPEC.links, upper_arm_m=SPEC.links.upper_arm_m + 0.002)
    )
    preset = tmp_path / "dr.yaml"
    preset.write_text("actuation: {}\n")
    prepare_finetune_dir(src, run, spec, preset, dr.to_dict(), max_steps=2048, wall_s=60.0)
    rd = RunDir(run)
    config = rd.read_config()
    assert config["spec_fingerprint"] == spec.fingerprint() != src.config["spec_fingerprint"]
    assert config["adapted_from"]["steps"] == src.steps
    # before any training the run's policy (checkpoint + rebuilt VecNormalize) IS the shipped one
    shipped_onnx = shipped()["reach-ppo"].path
    diff = max_action_diff(run, shipped_onnx, sample_observations(run, 300))
    assert diff < 1e-4, diff
    res = resume(run, progress=False)
    assert res.steps_done >= src.steps + 2048
    assert rd.read_status()["finished"] and rd.model_path.is_file()
    assert max_action_diff(run, shipped_onnx, sample_observations(run, 300)) > 1e-6  # it trained


def test_shipped_training_stats_carry_no_machine_paths() -> None:
    """A shipped file must not name the shipping machine's folders."""
    from sim2real.adapt.checkpoint import train_stats_text

    config = {
        "train": {"run_dir": "/home/someone/runs/x", "dr": "default"},
        "dr_source": "/a/b.yaml",
    }
    text = train_stats_text(config, 10, 1, None)
    assert "/home/someone" not in text and "/a/b.yaml" not in text and '"x"' in text
    for pol in shipped().values():
        if pol.checkpoint is None:
            continue
        stats = pol.checkpoint[1].read_text()
        assert '": "/' not in stats, pol.name  # no absolute path in any value
