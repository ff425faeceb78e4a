"""Joystick publishers: keyboard, CAN device and replay, all through one :class:`Publisher`.

Each turns its input into validated joystick messages on ``legws/<robot>/joystick``
(:mod:`.publisher` holds the shared session, sequence numbers, recording and loop).
"""
