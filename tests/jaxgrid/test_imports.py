"""``import jaxgrid`` stays light: usable in any JAX project without the learner's stack."""

from __future__ import annotations

import subprocess
import sys

HEAVY = ("optax", "orbax", "matplotlib", "tqdm", "agents", "checker", "experiments")


def test_import_jaxgrid_pulls_in_no_learner_or_plotting_package():
    code = (
        "import sys, jaxgrid, jaxgrid.gym, jaxgrid.io, jaxgrid.language, jaxgrid.wrappers\n"
        f"print(sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY!r})))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout
