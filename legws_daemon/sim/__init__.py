"""The MuJoCo Sawyer stand-in: assets, world composition, control, IK, feasibility, episodes."""
