import os

from hypothesis import settings

# CI runs derandomised so a red build is reproducible; local runs keep exploring new examples.
settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")
