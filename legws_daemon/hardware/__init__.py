"""Hardware-profile adapters: one interface to the MuJoCo stand-in and the real robot."""
