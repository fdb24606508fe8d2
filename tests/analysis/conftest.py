from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest


@pytest.fixture(scope="package")
def cluster() -> Iterator[Any]:
    """The local cluster a batch starts by default, sized to 2 single-threaded workers, its dashboard on a free port.

    Shared by the batch and study tests (starting one costs each worker the imports of the analysis stack), and
    closed after them, so idle workers do not sit beside the rest of the suite.
    """
    from analysis.batch.cluster import ClusterSettings, cluster_client

    with cluster_client(ClusterSettings(workers=2, dashboard_address="127.0.0.1:0")) as client:
        assert len(client.scheduler_info()["workers"]) == 2
        yield client
