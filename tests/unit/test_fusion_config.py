"""Fusion settings from a deployment's TOML file: validation at the trust boundary, and the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.recording.replay import generate_recording
from skelfuse.cli import main
from skelfuse.fusion.config import (
    REMOVED,
    RENAMED,
    FusionConfigError,
    fusion_settings_as_dict,
    fusion_settings_from_mapping,
    load_fusion_settings,
)
from skelfuse.fusion.settings import FusionSettings


def write(tmp_path: Path, text: str, name: str = "fusion.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_a_file_overrides_only_what_it_names(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        """
        [fusion.smoothing]
        filter = "kalman"

        [fusion.mirror]
        walk_check_s = 0          # an int where a float is expected

        [fusion.weights]
        view_bins = false
        state_weights = [0, 0.5, 1]

        [fusion.bones]
        lock_samples = 120
        """,
    )
    settings = load_fusion_settings(path)
    assert settings.smoothing.filter == "kalman"
    assert settings.mirror.walk_check_s == 0.0 and isinstance(settings.mirror.walk_check_s, float)
    assert settings.weights.view_bins is False
    assert settings.weights.state_weights == (0.0, 0.5, 1.0)
    assert settings.bones.lock_samples == 120
    defaults = FusionSettings()
    assert settings.smoothing.one_euro_beta == defaults.smoothing.one_euro_beta
    assert settings.mirror.redecide == defaults.mirror.redecide
    assert settings.tracking == defaults.tracking
    assert load_fusion_settings(write(tmp_path, "", "empty.toml")) == defaults


def test_the_flat_keys_of_before_are_read_with_one_warning_naming_the_new_ones(
    tmp_path: Path,
) -> None:
    path = write(tmp_path, "[fusion]\nfilter = 'kalman'\nmirror_walk_check_s = 0\n")
    with pytest.warns(DeprecationWarning, match="flat keys are deprecated") as caught:
        settings = load_fusion_settings(path)
    assert len(caught) == 1
    message = str(caught[0].message)
    assert "filter -> smoothing.filter" in message
    assert "mirror_walk_check_s -> mirror.walk_check_s" in message
    assert settings.smoothing.filter == "kalman" and settings.mirror.walk_check_s == 0.0
    # The flat policy and the [fusion.alignment] table share a name: both are read.
    with pytest.warns(DeprecationWarning, match="alignment -> alignment.policy"):
        assert fusion_settings_from_mapping({"alignment": "phased"}).alignment.policy == "phased"
    with pytest.raises(FusionConfigError, match="filter: given twice"):
        fusion_settings_from_mapping({"filter": "none", "smoothing": {"filter": "kalman"}})


def test_every_problem_is_reported_at_once_by_key() -> None:
    with pytest.raises(FusionConfigError) as caught:
        fusion_settings_from_mapping(
            {
                "filtr": "kalman",
                "smoothing": {"filter": "median", "one_euro_beta": -1, "walk_check_s": 1},
                "mirror": {"walk_chek_s": 0.5},
                "weights": {"view_bins": 1, "state_weights": [0, 2, 1], "view_error_m": [1.5]},
                "tracking": {"min_frames": 2.5},
                "bones": 3,
            }
        )
    message = str(caught.value)
    assert "filtr: not a fusion setting (did you mean 'smoothing.filter'?)" in message
    assert (
        "smoothing.filter: expected one of 'one_euro', 'kalman', 'none', 'kalman_ca', got 'median'"
        in message
    )
    assert "smoothing.walk_check_s: not a fusion setting (did you mean 'mirror.walk_check_s'?)" in (
        message
    )
    assert "mirror.walk_chek_s: not a fusion setting (did you mean 'mirror.walk_check_s'?)" in (
        message
    )
    assert "weights.view_bins: expected true or false, got 1" in message
    assert "weights.view_error_m: removed: each sensor's error is learned" in message
    assert "smoothing.one_euro_beta: expected a finite number ≥ 0, got -1" in message
    assert "tracking.min_frames: expected a whole number ≥ 0, got 2.5" in message
    assert "weights.state_weights: each weight must be in [0, 1]" in message
    assert "bones: expected a table ([fusion.bones]), got 3" in message


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("[fusion\nfilter = 1", "not valid TOML"),
        ("[fusion]\n[server]\nport = 1", "only a [fusion] table is read here; also found server"),
        ("fusion = 3", "'fusion' must be a table"),
        ("[fusion.alignment]\ngrid = 'spline'", "alignment.grid: expected one of"),
    ],
)
def test_bad_files_name_the_file_and_the_problem(tmp_path: Path, text: str, expected: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(FusionConfigError) as caught:
        load_fusion_settings(path)
    assert str(caught.value).startswith(str(path)) and expected in str(caught.value)
    with pytest.raises(FusionConfigError, match="cannot read it"):
        load_fusion_settings(tmp_path / "missing.toml")


def test_every_setting_can_be_written_in_a_file() -> None:
    """A new settings field of a type the checker does not know fails here first."""
    as_dict = fusion_settings_as_dict(FusionSettings())
    assert set(as_dict) == set(FusionSettings.__dataclass_fields__)
    for group, values in as_dict.items():
        assert set(values) == set(type(getattr(FusionSettings(), group)).__dataclass_fields__)
    json.dumps(as_dict)  # JSON-ready for the API
    written = {
        group: {key: value for key, value in values.items() if value is not None}
        for group, values in as_dict.items()
    }
    assert fusion_settings_from_mapping(written) == FusionSettings()


def test_every_flat_key_of_before_has_a_new_place_or_a_reason() -> None:
    """The record the codemod and the loader share: each old key maps to a field that exists."""
    as_dict = fusion_settings_as_dict(FusionSettings())
    for old, new in RENAMED.items():
        group, key = new.split(".")
        assert key in as_dict[group], f"{old} -> {new}: no such field"
    assert not set(RENAMED) & set(REMOVED)
    for old, reason in REMOVED.items():
        with pytest.raises(FusionConfigError, match=f"{old}: removed: "):
            fusion_settings_from_mapping({old: 1})
        assert reason and "\n" not in reason


def test_replay_fuses_with_the_files_settings_and_refuses_a_bad_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recording = tmp_path / "take.sfrec"
    generate_recording(recording, sensors=2, persons=1, duration_s=2.0, seed=5)
    outputs = {}
    for name, text in [("defaults", ""), ("none", '[fusion.smoothing]\nfilter = "none"\n')]:
        config = write(tmp_path, text, f"{name}.toml")
        out = tmp_path / f"{name}.jsonl"
        argv = ["replay", str(recording), "--out", str(out), "--fusion-config", str(config)]
        assert main(argv) == 0
        outputs[name] = out.read_text(encoding="utf-8")
    assert outputs["defaults"] != outputs["none"], "the filter setting changed nothing"

    bad = write(tmp_path, "[fusion.smoothing]\nfilter = 'median'\n", "bad.toml")
    assert main(["replay", str(recording), "--fusion-config", str(bad)]) == 2
    assert "filter: expected one of" in capsys.readouterr().err
    jsonl = tmp_path / "defaults.jsonl"
    assert main(["export", str(jsonl), "--export", "csv", "--fusion-config", str(bad)]) == 2
    assert "fused already" in capsys.readouterr().err


def test_the_server_takes_the_file_from_the_environment_too(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    from skelfuse.cli import build_parser

    assert build_parser().parse_args(["server"]).fusion_config is None
    path = str(write(tmp_path, "[fusion]\n"))
    monkeypatch.setenv("SKELFUSE_FUSION_CONFIG", path)
    assert build_parser().parse_args(["server"]).fusion_config == path
    assert build_parser().parse_args(["server", "--fusion-config", "x.toml"]).fusion_config == (
        "x.toml"
    )
