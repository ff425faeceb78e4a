"""The robot model: the Sawyer's MuJoCo world, its kinematics and IK, grasp feasibility,
the gripper's geometry, motion primitives and the motion planner of assistance; the
optimiser's reachability map and offscreen renders of the world."""
