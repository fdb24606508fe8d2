"""The samples table a run ends with: calibrated BRDF readings as CSV, and its Parquet copy and schema."""
