"""The Dobot MG400: kinematics and limits, flange frames, the TCP/IP protocol (sans-IO). Shared by the
simulated arm (:mod:`simshear_gym.sim.mg400_arm`) and the real-robot path (:mod:`simshear_gym.real`)."""
