"""Batch work on a Dask cluster: many runs or MERL files analysed (``gonio batch analyze``), simulation studies run
(``gonio batch study``), each input or study cell one idempotent task, a Parquet catalogue of the results.

Dask is imported only inside the functions that need a cluster, so importing this package stays cheap.
"""
