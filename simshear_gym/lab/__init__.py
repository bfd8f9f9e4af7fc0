"""The lab's workflows on the hardware: two-arm experiments, the arms' calibration, data collection and the
rehearsal rig.

Drivers (client, safety layer, camera, emulator, ``RealTactileEnv``) live in :mod:`simshear_gym.real`; this room
composes them into what a lab runs: :mod:`~simshear_gym.lab.frames` (the base-to-base calibration file and the
plate on the leader's flange), :mod:`~simshear_gym.lab.rig` (two emulated MG400s and a rehearsal camera),
:mod:`~simshear_gym.lab.experiment` (``simshear experiment tracking``), :mod:`~simshear_gym.lab.calibrate`
(``simshear calibrate-arms``) and :mod:`~simshear_gym.lab.collect_protocol` (the ``[collect]`` table of a sensor's
config: which contacts to record and the arm's path for each).
"""
