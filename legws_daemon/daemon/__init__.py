"""The deployment daemon: joystick in, intent inference and commit, assistance, robot out.

Pure per-tick logic (:mod:`.inbox`, :mod:`.ticker`, :mod:`.assist`, :mod:`.controller`) is
apart from its wiring to zenoh, Rerun and signals (:mod:`.service`).
"""
