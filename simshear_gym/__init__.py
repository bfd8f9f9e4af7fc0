"""simshear-gym: sim-to-real tactile robotics with shear.

Subpackages: ``data`` (tactile-data format, labels, replay), ``sim`` (PyBullet world, TacTip, stimuli,
shear tracker), ``models``, ``train``, ``evaluate``, ``envs``, ``control``, ``real``.
"""

__version__ = "0.1.0"
