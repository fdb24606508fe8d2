"""The gonio command line: the thin top layer.

It reaches every package and nothing imports it. One module per command group (cli_*.py), the demo
(demo.py) and ``gonio models`` (models_demo.py); ``cli.py`` holds the parser and the exit codes.
"""

import model.runtime  # noqa: F401 (the thread pools' policy, before anything starts numba or BLAS)
