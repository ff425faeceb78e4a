"""``legws demo``: the daemon and a simulated user through a whole task graph."""
