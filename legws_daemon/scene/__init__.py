"""Scenes: objects, grasps, layouts and their constraints."""
