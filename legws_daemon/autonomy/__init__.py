"""The shared-autonomy loop: one typed state machine run by the daemon and by ``legws eval``.

Modes and their transitions (:mod:`.modes`), typed events (:mod:`.events`), the operator's
input (:mod:`.inputs`), assistance (:mod:`.assistant`, :mod:`.cancel`), reset recovery
(:mod:`.recovery`), the layout the robot works in (:mod:`.layouts`) and the controller that
ties them together once per tick (:mod:`.controller`).
"""
