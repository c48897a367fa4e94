"""The math of ffmpc, free of ROS and of any simulator.

Robot models (:mod:`~ffmpc_core.robots`), the three OCP formulations of the force-feedback
paper (:mod:`~ffmpc_core.rigid_contact`, :mod:`~ffmpc_core.lowpass`,
:mod:`~ffmpc_core.soft_contact`), the MPC (:mod:`~ffmpc_core.mpc`), the tasks, the sensing and
actuation models, the torque PID and the low-level loop, the metrics, the scenario schema
(:mod:`~ffmpc_core.scenario`), the one closed loop (:mod:`~ffmpc_core.runner`), and the safe
maximal impacts of the second paper (:mod:`ffmpc_core.impact`).
"""
