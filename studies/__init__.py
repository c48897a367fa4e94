"""The papers' experiments, each over the plants and the runner of :mod:`sim_bridge`.

Modules:
    study: the polishing study (Kleff et al. 2024, Sec. VI: formulations × seeds, on Dask).
    impact_study: the safe-maximal-impact experiment (Dehio & Kheddar 2020, Sec. VI, Fig. 4).
    exploration: the contact learner's exploration (Dehio & Kheddar 2020, Sec. V–VI).
    bench_impact: the impact planner's cycle time on the impact study's problems.

Layers: ``ffmpc_core`` ← ``sim_bridge`` ← ``studies`` ← ``ffmpc_ros`` (the command line calls
the studies); the controllers the experiments run are objects of ``ffmpc_core`` (e.g.
:mod:`ffmpc_core.impact.controllers`), a study only builds them, runs the plant and logs.
"""
