"""The robot model: an arm's MuJoCo world (the arm from :mod:`legws_daemon.arms`), its
kinematics and IK, grasp feasibility, the gripper's geometry, motion primitives and the
motion planner of assistance; the optimiser's reachability map and offscreen renders of the
world."""
