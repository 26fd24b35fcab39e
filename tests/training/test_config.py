"""training.config: help text from docstrings, every field type on the command line,
nested ``--model.x`` flags, deprecated spellings, model configs read from a signature,
JSON round trips; and every trainer's ``--help`` documents every field."""

from __future__ import annotations

import dataclasses
import importlib
import typing
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import pytest

from training.config import (
    build_parser,
    config_of,
    differences,
    field_help,
    from_dict,
    model_config,
    parse,
    to_dict,
)


class Net:
    """A model class documented diffusers-style.

    Args:
        widths: channels per level; level ``i`` halves
            the resolution.
        act, norm: the activation and the normalisation.
        scale: an optional scale (none: off).

    Example:
        >>> Net()  # doctest: +SKIP
    """

    def __init__(
        self,
        widths: Sequence[int] = (8, 16),
        act: str = "silu",
        norm: str = "group",
        scale: float | None = None,
        **kwargs,
    ):
        self.config = dict(widths=list(widths), act=act, norm=norm, scale=scale, _class_name="Net")


NetConfig = model_config(Net, name="NetConfig", module=__name__)


@dataclass
class Run:
    """A run.

    Attributes:
        steps: optimizer steps.
        kind: the schedule.
        resume: continue a run.
        tag: a label (none: no label).
        extra: free JSON.
        model: the architecture.
    """

    steps: int = 10
    kind: Literal["constant", "cosine"] = "cosine"
    resume: bool = True
    tag: str | None = None
    extra: dict = field(default_factory=dict)
    model: NetConfig = field(default_factory=lambda: NetConfig(act="relu"))


def test_field_help_reads_the_args_section():
    docs = field_help(Net)
    assert docs == {
        "widths": "channels per level; level i halves the resolution.",
        "act": "the activation and the normalisation.",
        "norm": "the activation and the normalisation.",
        "scale": "an optional scale (none: off).",
    }


def test_model_config_follows_the_signature():
    assert [f.name for f in dataclasses.fields(NetConfig)] == ["widths", "act", "norm", "scale"]
    assert NetConfig() == NetConfig(widths=(8, 16), act="silu", norm="group", scale=None)
    assert typing.get_type_hints(NetConfig)["widths"] == tuple[int, ...]
    assert NetConfig(widths=[1, 2]).widths == (1, 2)  # JSON lists become tuples
    assert field_help(NetConfig)["widths"] == field_help(Net)["widths"]
    with pytest.raises(dataclasses.FrozenInstanceError):
        NetConfig().act = "x"
    with pytest.raises(ValueError, match="no arguments"):
        model_config(Net, name="X", exclude=("depth",))


def test_every_type_on_the_command_line(capsys):
    run = parse(
        Run,
        ["--steps", "3", "--kind", "constant", "--no-resume", "--tag", "a", "--extra", '{"k": 1}']
        + ["--model.widths", "4,8,16", "--model.scale", "0.5"],
    )
    assert run == Run(
        steps=3, kind="constant", resume=False, tag="a", extra={"k": 1}, model=NetConfig((4, 8, 16), "relu", scale=0.5)
    )
    assert parse(Run, ["--tag", "none", "--model.scale", "None"]).tag is None
    assert parse(Run, []).model.act == "relu"  # the field's default_factory, not the class default
    with pytest.raises(SystemExit):
        parse(Run, ["--kind", "linear"])
    assert "invalid choice" in capsys.readouterr().err


def test_help_shows_every_field_with_its_text_and_default(capsys):
    with pytest.raises(SystemExit):
        parse(Run, ["--help"], prog="run")
    out = " ".join(capsys.readouterr().out.split())
    for text in (
        "--steps INT optimizer steps. (default: 10)",
        "--resume, --no-resume continue a run. (default: true)",
        "--tag STR a label (none: no label). (default: none)",
        "--model.widths INT,... channels per level; level i halves the resolution. (default: 8,16)",
        "--model.act STR the activation and the normalisation. (default: relu)",
    ):
        assert text in out


def test_deprecated_spelling_sets_the_new_field_and_says_so(capsys):
    run = parse(Run, ["--width", "2,4"], prog="run", aliases={"--width": "model.widths"})
    assert run.model.widths == (2, 4)
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--width is deprecated" in err and "--model.widths" in err
    with pytest.raises(ValueError, match="no field"):
        build_parser(Run, aliases={"--x": "model.nothing"})


def test_json_round_trip_and_config_of():
    run = Run(steps=2, model=NetConfig(widths=(1, 2, 3)))
    assert from_dict(Run, to_dict(run)) == run
    with pytest.raises(TypeError, match="no fields"):
        from_dict(Run, {"stepz": 1})
    assert config_of(NetConfig, Net(widths=(3, 4))) == NetConfig(widths=(3, 4))  # "_class_name" is skipped


def test_differences_skip_none_and_ignored_fields():
    saved = NetConfig(widths=(8, 16), scale=2.0)
    assert differences(NetConfig(), saved) == {}  # requested scale None: the model's default
    assert differences(NetConfig(act="relu"), saved) == {"act": ("relu", "silu")}
    assert differences(NetConfig(act="relu"), saved, ignore=("act",)) == {}


def _fields(cls, prefix=""):
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if dataclasses.is_dataclass(hints[f.name]):
            yield from _fields(hints[f.name], f"{prefix}{f.name}.")
        else:
            yield prefix + f.name


@pytest.mark.parametrize("module", ["relight.diffusion.train", "relight.bieron.train", "estimator.train"])
def test_every_trainer_flag_has_help_text_and_a_default(module):
    trainer = importlib.import_module(module)
    parser = build_parser(trainer.TrainConfig)
    actions = {a.dest: a for a in parser._actions if a.dest != "help"}
    assert set(actions) == set(_fields(trainer.TrainConfig))  # one flag per field, nested ones included
    for dest, action in actions.items():
        text, _, default = action.help.rpartition(" (default: ")
        assert text.strip() and default.endswith(")"), f"{module}: --{dest} has no help text: {action.help!r}"
    cfg = trainer.parse_args([])
    assert cfg == trainer.TrainConfig()  # the command line's defaults are the dataclass's
    assert not cfg.ckpt_dir.startswith("/")  # no developer machine's path
