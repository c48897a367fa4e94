"""The papers' experiments, each over the plants and the runner of :mod:`sim_bridge`.

Modules:
    study: the polishing study (Kleff et al. 2024, Sec. VI: formulations × seeds, on Dask).
    impact_study: the safe-maximal-impact experiment (Dehio & Kheddar 2020, Sec. VI, Fig. 4).
    exploration: the contact learner's exploration (Dehio & Kheddar 2020, Sec. V–VI).
    bench_impact: the impact planner's cycle time on the impact study's problems.
    tune: the Optuna search of one controller's cost weights.
    cli: their ``ffmpc`` commands (``study``, ``tune``, ``bench impact``), entry points that
        ``ffmpc_ros.cli`` discovers (:mod:`ffmpc_ros.cli_extensions`).

Layers: ``ffmpc_core`` ← ``sim_bridge`` ← ``ffmpc_ros`` ← ``studies`` (the top layer: the
command line runs the studies without importing them); the experiments' configurations and
metrics are in :mod:`ffmpc_core.impact.scenario` and :mod:`ffmpc_core.impact.metrics`, their
PyBullet scenes in :mod:`sim_bridge.scenes`; the controllers the experiments run are objects
of ``ffmpc_core`` (e.g. :mod:`ffmpc_core.impact.controllers`), a study only builds them, runs
the plant and logs.
"""
