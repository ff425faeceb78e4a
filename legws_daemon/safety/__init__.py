"""Safety decisions, pure and tested: the envelope every command passes through."""
