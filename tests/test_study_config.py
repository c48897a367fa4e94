"""One configuration system for every study: a schema built from any tree of frozen dataclasses
(ffmpc_core.scenario.dataclass_schema / ConfigSchema), the impact and exploration scenario files
holding today's dataclass defaults, and ``--scenario/--set`` on ``ffmpc study impact|explore``."""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field

import pytest
import yaml

from ffmpc_core.declaration import param
from ffmpc_core.errors import ConfigError
from ffmpc_core.impact.scenario import (
    EXPLORATION_SCHEMA,
    IMPACT_SCHEMA,
    ExplorationConfig,
    ImpactStudyConfig,
    load_exploration_config,
    load_impact_config,
)
from ffmpc_core.scenario import (
    BOOL,
    FLOAT,
    FLOAT_OR_FLOATS,
    FLOATS,
    INT,
    SCENARIO_DIR,
    STR,
    ConfigSchema,
    dataclass_schema,
    flatten,
    load_scenario,
    public_name,
)
from ffmpc_ros.cli import main

ONE_LINE = re.compile(r"^[\w.]+ = .+: (expected .+|unknown scenario parameter.*)$")


@dataclass(frozen=True)
class _Inner:
    gain: float = param(2.0, "1/s", (0.0, 10.0), "a gain")
    count: int = param(3, "", (1, 5), "a count")
    axis: tuple[float, float] = param((0.0, 1.0), "", (-1.0, 1.0), "an axis")


@dataclass(frozen=True)
class _Outer:
    name: str = param("a", "", ["a", "b"], "a choice")
    enabled: bool = param(True, "", None, "a switch")
    inner: _Inner = field(default_factory=_Inner)
    speeds: tuple[float, ...] | None = param(None, "m/s", (0.0, 1.0), "speeds")
    diag: float | tuple[float, ...] = param(1.0, "", (0.0, 5.0), "a diagonal")


@dataclass(frozen=True)
class _Undeclared:
    declared: float = param(1.0, "", (0.0, 2.0), "a declared field")
    plain: float = 1.0


_TOY_NAMES = ("name", "enabled", "ctl.gain", "ctl.count", "ctl.axis", "speeds", "diag")
_TOY = ConfigSchema.of(_Outer, {"inner.": "ctl."})


def test_schema_kinds_ranges_and_names_from_the_annotations():
    p = _TOY.params
    assert tuple(p) == _TOY_NAMES
    assert (p["name"].kind, p["name"].choices) == (STR, ("a", "b"))
    assert p["enabled"].kind == BOOL
    assert (p["ctl.gain"].kind, p["ctl.gain"].unit, p["ctl.gain"].range) == (FLOAT, "1/s", (0, 10))
    assert p["ctl.count"].kind == INT
    assert (p["ctl.axis"].kind, p["ctl.axis"].length) == (FLOATS, 2)
    assert (p["speeds"].kind, p["speeds"].length, p["speeds"].optional) == (FLOATS, None, True)
    assert p["diag"].kind == FLOAT_OR_FLOATS
    assert public_name("inner.gain", {"inner.": "ctl."}) == "ctl.gain"
    assert _TOY.paths["ctl.gain"] == "inner.gain"


def test_schema_builds_checks_and_refuses_with_the_scenario_messages():
    cfg = _TOY.build({"ctl.gain": 3, "ctl.axis": [1, 0], "speeds": [0.2, 0.3], "name": "b"})
    assert cfg == _Outer(name="b", inner=_Inner(gain=3.0, axis=(1.0, 0.0)), speeds=(0.2, 0.3))
    assert isinstance(cfg.inner.gain, float)
    assert _TOY.build({"speeds": None}) == _Outer()
    assert _TOY.flatten(cfg)["ctl.axis"] == (1.0, 0.0)
    for flat, expected in [
        ({"ctl.gain": 11.0}, "ctl.gain = 11.0: expected a number in [0, 10] 1/s"),
        ({"ctl.gain": True}, "ctl.gain = True: expected a number"),
        ({"ctl.count": 2.5}, "ctl.count = 2.5: expected an integer in [1, 5]"),
        ({"ctl.axis": [1.0]}, "ctl.axis = [1.0]: expected a list of 2 numbers"),
        ({"speeds": [-1.0]}, "expected a list of numbers in [0, 1] m/s or null"),
        ({"name": "c"}, "name = 'c': expected one of 'a', 'b'"),
        ({"enabled": 1}, "enabled = 1: expected true or false"),
        ({"ctl.gian": 1.0}, "unknown scenario parameter; did you mean ctl.gain"),
        ({"inner.gain": 1.0}, "inner.gain = 1.0: unknown scenario parameter"),
    ]:
        with pytest.raises(ConfigError) as info:
            _TOY.build(flat)
        assert ONE_LINE.match(str(info.value)), info.value
        assert expected in str(info.value)


def test_schema_refuses_a_field_without_a_declaration():
    with pytest.raises(AssertionError, match=r"plain \(_Undeclared.plain\) is not declared"):
        dataclass_schema(_Undeclared)
    assert list(dataclass_schema(_Undeclared, given={"plain": _TOY.params["diag"]})) == [
        "declared",
        "plain",
    ]
    with pytest.raises(AssertionError, match="two fields named ctl.gain"):
        dataclass_schema(_Outer, {"inner.": "ctl.", "diag": "ctl.gain"})


@pytest.mark.parametrize(
    "schema, name, default",
    [
        (IMPACT_SCHEMA, "impact", ImpactStudyConfig()),
        (EXPLORATION_SCHEMA, "explore", ExplorationConfig()),
    ],
)
def test_scenario_file_holds_every_parameter_at_its_dataclass_default(schema, name, default):
    assert schema.load(name) == default
    doc = yaml.safe_load((SCENARIO_DIR / f"{name}.yaml").read_text(encoding="utf-8"))
    in_file = set()
    for section, body in doc.items():
        params = flatten(body["ros__parameters"])
        in_file |= {k if section == "/**" else f"{section}.{k}" for k in params}
    assert in_file == set(schema.params)
    assert schema.flatten(schema.load(name)) == schema.flatten(default)


def test_study_names_read_well_and_overrides_reach_the_config():
    cfg = load_impact_config(
        "impact",
        {
            "plant.dice_stiffness": 3000.5,
            "planner.prior_stiffness": 2000,
            "planner.horizon": 15,
            "mpc.horizon": 8,
            "mpc.weights.posture": 2.0,
            "touch.stiffness_factors": [0.5, 3.0],
            "learner.min_samples": 30,
        },
    )
    assert cfg.dice.stiffness == 3000.5 and cfg.prior_stiffness == 2000.0
    assert cfg.planner.horizon == 15 and cfg.mpc_horizon == 8
    assert cfg.mpc_weights.posture == 2.0 and cfg.mpc_weights.joint_velocity == 0.1
    assert cfg.touch.stiffness_factors == (0.5, 3.0) and cfg.learner_min_samples == 30
    exp = load_exploration_config("explore", {"gains.position": 300, "guard.prior_damping": 50})
    assert exp.gains.position == 300.0 and exp.prior_damping == 50.0
    with pytest.raises(ConfigError, match="did you mean plant.dice_stiffness"):
        load_impact_config("impact", {"plant.dice_stifness": 3000})
    with pytest.raises(ConfigError, match=r"plant.dice_stiffness = -1: expected a number in"):
        load_impact_config("impact", {"plant.dice_stiffness": -1})
    # a cross-field rule of the dataclass still holds after the schema's per-field check
    with pytest.raises(ConfigError, match="whole number of plant steps"):
        load_impact_config("impact", {"mpc.period": 0.0025})


def test_study_scenarios_are_not_node_graph_scenarios():
    with pytest.raises(ConfigError, match="ffmpc study impact"):
        load_scenario("impact")
    with pytest.raises(ConfigError, match="unknown node section"):
        IMPACT_SCHEMA.load(SCENARIO_DIR / "polishing.yaml")


def test_cli_study_impact_set_reaches_the_config(tmp_path, capsys):
    """One real short run (baseline approach, 0.3 s: it does not reach the dice)."""
    out = tmp_path / "impact"
    code = main(
        [
            "study",
            "impact",
            "--runs",
            "baseline+admittance",
            "--duration",
            "0.3",
            "--set",
            "plant.dice_stiffness=3000",
            "--set",
            "planner.prior_damping=12.5",
            "--set",
            "touch.touch_force=12",
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    assert code in (0, 1), capsys.readouterr().err  # 1: the 0.3 s run never touched the dice
    config = json.loads((out / "results.json").read_text())["config"]
    assert config["dice"]["stiffness"] == 3000.0
    assert config["prior_damping"] == 12.5
    assert config["touch"]["touch_force"] == 12.0
    assert config["duration"] == 0.3
    assert "planner prior 2400 N/m, 12.5 N·s/m" in capsys.readouterr().out


def test_cli_study_explore_set_and_shorthands_reach_the_config(monkeypatch, tmp_path, capsys):
    import studies.exploration as exploration

    seen = {}

    def fake_study(materials, cfg, progress=True, **execution):
        seen["materials"], seen["cfg"], seen["execution"] = materials, cfg, execution
        return []

    monkeypatch.setattr(exploration, "run_exploration_study", fake_study)
    scenario = tmp_path / "slow.yaml"
    scenario.write_text("/**:\n  ros__parameters:\n    base: explore\n    dwell: 0.5\n")
    argv = ["study", "explore", "--materials", "foam", "--scenario", str(scenario)]
    argv += ["--approach-speed", "0.004", "--set", "gains.velocity=30", "--set", "sine_cycles=2"]
    argv += ["--out", str(tmp_path / "out"), "--workers", "2"]
    main(argv)
    cfg = seen["cfg"]
    assert seen["execution"]["workers"] == 2 and seen["execution"]["scheduler"] is None
    assert seen["execution"]["out_dir"] == str(tmp_path / "out")
    assert seen["materials"] == ("foam",)
    assert cfg == ExplorationConfig(
        dwell=0.5,
        approach_speed=0.004,
        sine_cycles=2,
        gains=ExplorationConfig().gains.__class__(velocity=30.0),
    )


def test_cli_study_explore_real_short_run(capsys, tmp_path):
    code = main(
        [
            "study",
            "explore",
            "--out",
            str(tmp_path / "explore"),
            "--workers",
            "1",
            "--materials",
            "foam",
            "--set",
            "sine_cycles=1",
            "--set",
            "impact_velocities=[0.2]",
        ]
    )
    out = capsys.readouterr().out
    assert code == 0
    assert re.search(r"foam after impact 1 at 0\.(19|20)\d m/s", out)
    assert "after impact 2" not in out
