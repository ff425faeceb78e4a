"""Tests of the joystick publishers (keyboard, CAN, replay) and their shared publisher."""
