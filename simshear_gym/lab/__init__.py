"""The lab's workflows on the hardware: what a lab runs with its arms and sensor, over the drivers of
:mod:`simshear_gym.real`; :mod:`~simshear_gym.lab.collect_protocol`: the ``[collect]`` table of a sensor's config
(which contacts to record and the arm's path for each)."""
