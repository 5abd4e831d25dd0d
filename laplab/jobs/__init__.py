"""The console job service: the SQLite job store, runners and the worker process."""
