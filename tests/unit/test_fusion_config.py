"""Fusion settings from a deployment's TOML file: validation at the trust boundary, and the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.replay import generate_recording
from skelfuse.cli import main
from skelfuse.fusion.config import (
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
        [fusion]
        filter = "kalman"
        mirror_walk_check_s = 0          # an int where a float is expected
        use_distance = true
        state_weights = [0, 0.5, 1]
        bone_estimate_lock_samples = 120
        """,
    )
    settings = load_fusion_settings(path)
    assert settings.filter == "kalman"
    assert settings.mirror_walk_check_s == 0.0 and isinstance(settings.mirror_walk_check_s, float)
    assert settings.use_distance is True
    assert settings.state_weights == (0.0, 0.5, 1.0)
    assert settings.bone_estimate_lock_samples == 120
    defaults = FusionSettings()
    assert settings.one_euro_beta == defaults.one_euro_beta
    assert settings.bone_length_fit == defaults.bone_length_fit
    assert load_fusion_settings(write(tmp_path, "", "empty.toml")) == defaults


def test_every_problem_is_reported_at_once_by_key(tmp_path: Path) -> None:
    with pytest.raises(FusionConfigError) as caught:
        fusion_settings_from_mapping(
            {
                "filtr": "kalman",
                "filter": "median",
                "use_facing": 1,
                "one_euro_beta": -1,
                "track_min_frames": 2.5,
                "state_weights": [0, 2, 1],
                "distance_best_m": [1.5],
                "outlier_scale_m": float("nan"),
            }
        )
    message = str(caught.value)
    assert "filtr: not a fusion setting (did you mean 'filter'?)" in message
    assert "filter: expected one of 'one_euro', 'kalman', 'none', 'kalman_ca', got 'median'" in (
        message
    )
    assert "use_facing: expected true or false, got 1" in message
    assert "one_euro_beta: expected a finite number ≥ 0, got -1" in message
    assert "track_min_frames: expected a whole number ≥ 0, got 2.5" in message
    assert "state_weights: each weight must be in [0, 1]" in message
    assert "distance_best_m: expected a list of 2 numbers" in message
    assert "outlier_scale_m: expected a finite number" in message


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("[fusion\nfilter = 1", "not valid TOML"),
        ("[fusion]\n[server]\nport = 1", "only a [fusion] table is read here; also found server"),
        ("fusion = 3", "'fusion' must be a table"),
        ("[fusion]\nbone_length_fit = 'spline'", "bone_length_fit: expected one of"),
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
    """A new FusionSettings field of a type the checker does not know fails here first."""
    as_dict = fusion_settings_as_dict(FusionSettings())
    assert set(as_dict) == set(FusionSettings.__dataclass_fields__)
    json.dumps(as_dict)  # JSON-ready for the API
    written = {key: value for key, value in as_dict.items() if value is not None}
    assert fusion_settings_from_mapping(written) == FusionSettings()


def test_replay_fuses_with_the_files_settings_and_refuses_a_bad_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recording = tmp_path / "take.sfrec"
    generate_recording(recording, sensors=2, persons=1, duration_s=2.0, seed=5)
    outputs = {}
    for name, text in [("defaults", ""), ("none", '[fusion]\nfilter = "none"\n')]:
        config = write(tmp_path, text, f"{name}.toml")
        out = tmp_path / f"{name}.jsonl"
        argv = ["replay", str(recording), "--out", str(out), "--fusion-config", str(config)]
        assert main(argv) == 0
        outputs[name] = out.read_text(encoding="utf-8")
    assert outputs["defaults"] != outputs["none"], "the filter setting changed nothing"

    bad = write(tmp_path, "[fusion]\nfilter = 'median'\n", "bad.toml")
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
