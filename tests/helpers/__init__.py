"""Shared test helpers, importable as ``helpers.<module>`` (pytest's ``pythonpath`` holds
``tests``)."""
