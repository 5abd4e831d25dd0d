"""Jobs: running training and evaluation under a supervisor (supervisor.py, sandbox.py)."""
