"""The paper-reproduction experiments (``python -m experiments.<name>``)."""
