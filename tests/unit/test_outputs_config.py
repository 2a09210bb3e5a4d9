"""Outputs from the command line and from a TOML file: each flag and table gives its
OutputSpec; a bad one is refused with a message that says what to type."""

from __future__ import annotations

from pathlib import Path

import pytest

from skelfuse.cli import build_parser
from skelfuse.cli.server import output_specs
from skelfuse.cli.values import UsageError
from skelfuse.server.output_config import VMC_PORT, OutputConfigError, load_outputs
from skelfuse.server.settings import OutputSpec


def _specs(*argv: str) -> tuple[OutputSpec, ...]:
    return output_specs(build_parser().parse_args(["server", *argv]))


def test_flags_give_one_output_each() -> None:
    assert _specs() == ()
    assert _specs("--osc", "10.0.0.2:9000", "--osc-rotations", "--vmc", "10.0.0.3", "--lsl") == (
        OutputSpec("osc", "10.0.0.2", 9000, rotations=True),
        OutputSpec("vmc", "10.0.0.3", VMC_PORT),
        OutputSpec("lsl"),
    )
    with pytest.raises(UsageError, match="port"):
        _specs("--osc", "10.0.0.2")


def test_a_toml_file_gives_its_outputs_and_names_what_is_wrong(tmp_path: Path) -> None:
    path = tmp_path / "outputs.toml"
    path.write_text(
        '[[outputs]]\nkind = "osc"\nport = 9000\nrotations = true\n\n'
        '[[outputs]]\nkind = "lsl"\nslots = 4\n'
    )
    assert load_outputs(path) == (
        OutputSpec("osc", "127.0.0.1", 9000, rotations=True),
        OutputSpec("lsl", slots=4),
    )
    assert _specs("--outputs-config", str(path), "--vmc", ":40000")[-1] == OutputSpec(
        "vmc", "127.0.0.1", 40000
    )
    for text, problem in (
        ('[[outputs]]\nkind = "osc"\n', "needs a port"),
        ('[[outputs]]\nkind = "midi"\n', "kind must be one of"),
        ('[[outputs]]\nkind = "osc"\nport = "9000"\n', "port must be a int"),
        ('[[outputs]]\nkind = "osc"\nport = 9000\nrotation = true\n', "unknown keys rotation"),
        ('[fusion]\nfilter = "none"\n', "only"),
    ):
        path.write_text(text)
        with pytest.raises(OutputConfigError, match=problem):
            load_outputs(path)


def test_each_kind_builds_its_output_with_its_metrics_name() -> None:
    pytest.importorskip("pylsl", reason="pylsl is not installed (pip install 'skelfuse[lsl]')")
    from skelfuse.server.outputs import build_output

    specs = (OutputSpec("osc", port=9000), OutputSpec("vmc", port=VMC_PORT), OutputSpec("lsl"))
    outputs = [build_output(spec, 30.0) for spec in specs]
    try:
        assert [o.name for o in outputs] == [
            "osc:127.0.0.1:9000",
            f"vmc:127.0.0.1:{VMC_PORT}",
            "lsl",
        ]
        assert [type(o.sink).__name__ for o in outputs] == ["OscSink", "VmcSink", "LslSink"]
    finally:
        for output in outputs:
            output.close()
