"""``ffmpc ft``: the wrist force/torque sensor (issue 27), an extension command (entry point
``ft`` of ``ffmpc.command``).

* ``ffmpc ft calibrate --out FILE``: the calibration routine of the scenario's wrist sensor and
  tool (the simulated poses of :mod:`ffmpc_core.ft_calibration`, the scenario's seed), checked,
  written to FILE for ``ft_sensor.calibration: file``;
* ``ffmpc ft tool-study``: polishing runs without a tool and with the 1 kg tool behind the
  wrist sensor, compensated or not (:mod:`studies.ft_tool`); prints E_λ per seed and the means.
"""

from __future__ import annotations

import argparse
import time

from ffmpc_core.errors import ConfigError
from ffmpc_ros.cli_args import new_path, parse_overrides, positive_int, seed_int
from ffmpc_ros.cli_extensions import CommandExtension

__all__ = ["FtCommand"]


def _calibrate(args: argparse.Namespace) -> int:
    from ffmpc_core.ft_calibration import (
        CalibrationNoise,
        calibration_poses,
        check_calibration,
        save_calibration,
        startup_calibration,
    )
    from ffmpc_core.polishing import device_generator, tool_load, wrist_sensor_model
    from ffmpc_core.robots import load_robot
    from ffmpc_core.scenario import load_scenario
    from ffmpc_ros.preflight import check_output, replace_forced

    check_output(args.out, force=args.force, what="--out")  # before anything runs (issue 28)
    scenario = load_scenario(args.scenario, parse_overrides(args.set))
    fs = scenario.ft_sensor
    if fs.model != "wrist":
        raise ConfigError("ffmpc ft calibrate needs ft_sensor.model: wrist (--set it)")
    robot = load_robot(scenario.robot)
    sensor = wrist_sensor_model(scenario, robot, device_generator(scenario.seed, "force_sensor"))
    noise = CalibrationNoise(
        fs.force_noise_std,
        fs.moment_noise_std,
        scenario.joint_sensor.position_noise_std,
        fs.calibration_samples,
    )
    poses = calibration_poses(robot)
    now = time.time()
    rng = device_generator(scenario.seed, "ft_calibration")
    calibration = startup_calibration(sensor, poses, noise, rng, now)
    check_calibration(calibration, robot, poses, tool_load(scenario), fs.calibration_max_age, now)
    replace_forced(args.out, args.force)
    save_calibration(calibration, args.out)
    print(f"{calibration.describe()}; {len(poses)} poses, condition {calibration.condition:.2f}")
    print(f"written: {args.out}")
    return 0


def _tool_study(args: argparse.Namespace) -> int:
    from studies.ft_tool import mean_force_error, tool_study, tool_table

    seeds = range(args.first_seed, args.first_seed + args.seeds)
    result = tool_study(
        args.scenario,
        seeds,
        tuple(args.variants),
        parse_overrides(args.set),
        workers=args.workers,
        progress=not args.no_progress,
    )
    print(tool_table(result))
    if "no tool" in result and "tool, compensated" in result:
        ref, comp = (
            mean_force_error(result, "no tool"),
            mean_force_error(result, "tool, compensated"),
        )
        print(
            f"mean E_λ: no tool {ref:.3f} N, 1 kg tool compensated {comp:.3f} N "
            f"({100.0 * (comp / ref - 1.0):+.1f} %)"
        )
    return 1 if any(row["failed"] for row in result.values()) else 0


class FtCommand(CommandExtension):
    """``ffmpc ft``: calibrate the wrist F/T sensor, or run the heavy-tool study."""

    help = "the wrist force/torque sensor: calibration file, heavy-tool study"
    description = (
        "The wrist F/T sensor of ft_sensor.model: wrist (ffmpc_core.wrist_ft): 'calibrate' runs "
        "the calibration poses of the scenario's tool and writes a calibration file; "
        "'tool-study' compares polishing runs without a tool and with a 1 kg tool behind the "
        "wrist sensor, compensated or not."
    )
    verb_dest = "ft"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        from studies.ft_tool import DEFAULT_VARIANTS, VARIANTS

        sub = parser.add_subparsers(dest="ft", required=True)
        cal = sub.add_parser(
            "calibrate",
            help="calibrate the wrist sensor and its tool, write a calibration file",
            description="The simulated calibration routine (16 wrist poses at rest, "
            "least squares: bias, mass, centre of mass) of the scenario's wrist sensor and "
            "tool; a calibration that is implausible or disagrees with the tool is refused "
            "(exit 2). The file is for ft_sensor.calibration: file.",
        )
        cal.add_argument("--out", required=True, type=new_path, help="calibration file (YAML)")
        cal.add_argument("--force", action="store_true", help="replace an existing --out")
        study = sub.add_parser(
            "tool-study",
            help="polishing without a tool vs a 1 kg tool, compensated or not",
            description="Polishing runs (the scenario's MPC and PID) per seed and variant; "
            "prints E_λ (true normal force, N) per seed, the means and their change against "
            "the run without a tool. Exit 1 if a run failed.",
        )
        study.add_argument("--seeds", type=positive_int, default=5, help="seeds (default 5)")
        study.add_argument("--first-seed", type=seed_int, default=0, help="first seed (0)")
        study.add_argument(
            "--variants",
            nargs="+",
            choices=list(VARIANTS),
            default=list(DEFAULT_VARIANTS),
            metavar="VARIANT",
            help=f"variants to run (default: {', '.join(DEFAULT_VARIANTS)}; also: "
            f"{', '.join(v for v in VARIANTS if v not in DEFAULT_VARIANTS)})",
        )
        study.add_argument(
            "--workers", type=positive_int, default=1, help="worker processes (default 1)"
        )
        study.add_argument("--no-progress", action="store_true", help="no progress bar")
        for p, main in ((cal, _calibrate), (study, _tool_study)):
            p.add_argument("--scenario", default="polishing", help="scenario (default polishing)")
            p.add_argument(
                "--set",
                action="append",
                metavar="NAME=VALUE",
                help="scenario override (repeatable), e.g. plant.tool_mass=1.5",
            )
            p.set_defaults(ft_main=main)

    def main(self, args: argparse.Namespace) -> int:
        return int(args.ft_main(args))
