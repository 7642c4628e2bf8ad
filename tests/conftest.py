"""Session-wide test settings.

The suite is dominated by XLA compile time on 2 CPU cores, not by running the (tiny)
programs, so tests compile with LLVM's optimisations off and XLA:CPU's per-op emitters
instead of its fusion emitters: same semantics, a fraction of the compile time (results may
differ from other settings in the last bits). Set before any JAX backend starts; a user's
own XLA_FLAGS are kept.
"""

import os

for _flag in ("--xla_backend_optimization_level=0", "--xla_cpu_use_fusion_emitters=false"):
    if _flag.split("=")[0] not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + _flag).strip()


import jax  # noqa: E402  (after XLA_FLAGS: the backend reads them when it starts)
import pytest  # noqa: E402


@pytest.fixture
def compiles():
    """Names of the JAX compile events while the test runs (public ``jax.monitoring``)."""
    events = []

    def listen(name, duration, **kwargs):
        if name.startswith("/jax/core/compile"):
            events.append(name)

    jax.monitoring.register_event_duration_secs_listener(listen)
    yield events
    jax.monitoring.unregister_event_duration_listener(listen)
