"""Multi-stage tasks: the task graph (stages, candidates, actions, transitions), the goal
poses each action aims at, and the state of a run through a graph."""
