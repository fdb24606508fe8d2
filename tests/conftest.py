import os

from hypothesis import settings

import model.runtime  # noqa: F401 (the thread pools' policy first, as every entry point: model/runtime.py)

# No test may depend on the machine's speed: a shared CI host loaded 5-10x runs an example in many times its
# usual time, so Hypothesis's per-example deadline is off in every profile (the default one included).
settings.register_profile("default", deadline=None)
# CI runs derandomised so a red build is reproducible; local runs keep exploring new examples.
settings.register_profile("ci", deadline=None, derandomize=True, print_blob=True)
settings.load_profile("ci" if os.environ.get("CI") else "default")
